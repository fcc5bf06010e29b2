/*
 * BlurTrack reference IMU firmware: an MPU-6050 on I2C streamed at 1 kHz in the BlurTrack
 * binary protocol (or the ASCII line protocol with BT_ASCII defined).
 *
 * Board: Teensy 4.0/4.1 (USB serial, any baud) or an Arduino with native USB (Leonardo, Zero,
 * Due). Classic Uno/Nano also work at 1 Mbaud (36 bytes x 1 kHz = 360 kbit/s) or at 200-500 Hz.
 * Wiring: MPU-6050 VCC 3.3 V, GND, SDA, SCL (400 kHz I2C), INT -> pin BT_INT_PIN.
 * Host: blurtrack record --imu "serial:///dev/ttyACM0?baud=921600" ...
 *
 * Sampling: DLPF_CFG=1 (188 Hz gyro bandwidth, 1 kHz internal rate), SMPLRT_DIV=0 -> 1 kHz,
 * data-ready interrupt. Each sample is stamped with micros() taken in the interrupt, i.e. at
 * the end of the sensor's sampling period (a constant offset the calibration absorbs).
 * Ranges: gyro +-2000 dps (16.4 LSB per deg/s), accel +-16 g (2048 LSB per g).
 */
#include <Wire.h>

#include "blurtrack_protocol.h"

#ifndef BT_INT_PIN
#define BT_INT_PIN 2
#endif
#ifndef BT_BAUD
#define BT_BAUD 921600
#endif

static const uint8_t MPU_ADDR = 0x68;
// micro-rad/s per LSB at +-2000 dps: (pi / 180) / 16.4 * 1e6
static const float GYRO_URADS_PER_LSB = 1064.2252f;
// micro-m/s^2 per LSB at +-16 g: 9.80665 / 2048 * 1e6
static const float ACCEL_UMPS2_PER_LSB = 4788.3984f;

static volatile uint32_t g_stamp_us = 0;
static volatile bool g_ready = false;
static uint16_t g_counter = 0;

static void mpu_write(uint8_t reg, uint8_t value) {
  Wire.beginTransmission(MPU_ADDR);
  Wire.write(reg);
  Wire.write(value);
  Wire.endTransmission();
}

static void on_data_ready() {
  g_stamp_us = micros();
  g_ready = true;
}

void setup() {
  Serial.begin(BT_BAUD);
  Wire.begin();
  Wire.setClock(400000);
  mpu_write(0x6B, 0x01);  // PWR_MGMT_1: wake up, clock from the X gyro PLL
  delay(100);
  mpu_write(0x1A, 0x01);  // CONFIG: DLPF_CFG = 1
  mpu_write(0x19, 0x00);  // SMPLRT_DIV = 0 -> 1 kHz
  mpu_write(0x1B, 0x18);  // GYRO_CONFIG: +-2000 dps
  mpu_write(0x1C, 0x18);  // ACCEL_CONFIG: +-16 g
  mpu_write(0x37, 0x10);  // INT_PIN_CFG: clear on any read
  mpu_write(0x38, 0x01);  // INT_ENABLE: data ready
  pinMode(BT_INT_PIN, INPUT);
  attachInterrupt(digitalPinToInterrupt(BT_INT_PIN), on_data_ready, RISING);
}

void loop() {
  if (!g_ready) return;
  noInterrupts();
  uint32_t t_us = g_stamp_us;
  g_ready = false;
  interrupts();

  uint8_t raw[14];
  Wire.beginTransmission(MPU_ADDR);
  Wire.write(0x3B);  // ACCEL_XOUT_H .. GYRO_ZOUT_L
  Wire.endTransmission(false);
  if (Wire.requestFrom(MPU_ADDR, (uint8_t)14) != 14) return;  // the host sees a counter gap
  for (int i = 0; i < 14; ++i) raw[i] = Wire.read();

  int32_t accel[3], gyro[3];
  for (int i = 0; i < 3; ++i) {
    int16_t a = (int16_t)((raw[2 * i] << 8) | raw[2 * i + 1]);
    int16_t g = (int16_t)((raw[8 + 2 * i] << 8) | raw[9 + 2 * i]);
    accel[i] = (int32_t)lroundf(a * ACCEL_UMPS2_PER_LSB);
    gyro[i] = (int32_t)lroundf(g * GYRO_URADS_PER_LSB);
  }
#ifdef BT_ASCII
  char line[160];
  size_t n = bt_encode_line(line, t_us, gyro, accel);
  Serial.write((const uint8_t *)line, n);
#else
  uint8_t frame[BT_MAX_FRAME];
  size_t n = bt_encode_frame(frame, g_counter, t_us, gyro, accel);
  Serial.write(frame, n);
#endif
  ++g_counter;  // counts samples read, so a skipped sample shows up as a gap
}
