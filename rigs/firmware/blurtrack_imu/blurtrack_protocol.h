/*
 * BlurTrack IMU wire protocol, device side (plain C99, no Arduino dependency, so that the
 * host test suite compiles it with gcc and checks it byte for byte against rigs/protocol.py).
 * Layout and scaling: docs/recording.md.
 */
#ifndef BLURTRACK_PROTOCOL_H
#define BLURTRACK_PROTOCOL_H

#include <stdint.h>
#include <stdio.h>
#include <string.h>

#define BT_SYNC0 0xA5
#define BT_SYNC1 0x5A
#define BT_TYPE_GYRO 0x01
#define BT_TYPE_GYRO_ACCEL 0x02
#define BT_MAX_FRAME 36

/* CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF, no reflection, no final xor. */
static inline uint16_t bt_crc16(const uint8_t *data, size_t n) {
  uint16_t crc = 0xFFFF;
  for (size_t i = 0; i < n; ++i) {
    crc ^= (uint16_t)data[i] << 8;
    for (int b = 0; b < 8; ++b) {
      crc = (crc & 0x8000) ? (uint16_t)((crc << 1) ^ 0x1021) : (uint16_t)(crc << 1);
    }
  }
  return crc;
}

static inline size_t bt_put_u16(uint8_t *p, uint16_t v) {
  p[0] = (uint8_t)(v & 0xFF);
  p[1] = (uint8_t)(v >> 8);
  return 2;
}

static inline size_t bt_put_u32(uint8_t *p, uint32_t v) {
  for (int i = 0; i < 4; ++i) p[i] = (uint8_t)(v >> (8 * i));
  return 4;
}

/*
 * One binary frame into out[BT_MAX_FRAME]; returns its length (24 or 36).
 * gyro_urads: rates in micro-rad/s; accel_umps2: micro-m/s^2, or NULL for a gyro-only frame.
 */
static inline size_t bt_encode_frame(uint8_t *out, uint16_t counter, uint32_t t_us,
                                     const int32_t gyro_urads[3], const int32_t *accel_umps2) {
  size_t n = 0;
  out[n++] = BT_SYNC0;
  out[n++] = BT_SYNC1;
  out[n++] = accel_umps2 ? 31 : 19;
  out[n++] = accel_umps2 ? BT_TYPE_GYRO_ACCEL : BT_TYPE_GYRO;
  n += bt_put_u16(out + n, counter);
  n += bt_put_u32(out + n, t_us);
  for (int i = 0; i < 3; ++i) n += bt_put_u32(out + n, (uint32_t)gyro_urads[i]);
  if (accel_umps2) {
    for (int i = 0; i < 3; ++i) n += bt_put_u32(out + n, (uint32_t)accel_umps2[i]);
  }
  n += bt_put_u16(out + n, bt_crc16(out + 2, n - 2));
  return n;
}

/* XOR of the bytes before '*' (NMEA 0183 checksum). */
static inline uint8_t bt_nmea_checksum(const char *s, size_t n) {
  uint8_t x = 0;
  for (size_t i = 0; i < n; ++i) x ^= (uint8_t)s[i];
  return x;
}

/*
 * One ASCII line "t_us,gx,gy,gz[,ax,ay,az]*XX\n" into out (at least 160 bytes); returns its
 * length. Rates in rad/s and accelerations in m/s^2, printed from the integer micro-units with
 * six decimals (printf of floats is missing or slow on small AVR boards).
 */
static inline size_t bt_format_micro(char *out, int32_t v) {
  uint32_t a = v < 0 ? (uint32_t)(-(int64_t)v) : (uint32_t)v;
  return (size_t)sprintf(out, "%s%lu.%06lu", v < 0 ? "-" : "", (unsigned long)(a / 1000000UL),
                         (unsigned long)(a % 1000000UL));
}

static inline size_t bt_encode_line(char *out, uint32_t t_us, const int32_t gyro_urads[3],
                                    const int32_t *accel_umps2) {
  size_t n = (size_t)sprintf(out, "%lu", (unsigned long)t_us);
  for (int i = 0; i < 3; ++i) {
    out[n++] = ',';
    n += bt_format_micro(out + n, gyro_urads[i]);
  }
  if (accel_umps2) {
    for (int i = 0; i < 3; ++i) {
      out[n++] = ',';
      n += bt_format_micro(out + n, accel_umps2[i]);
    }
  }
  n += (size_t)sprintf(out + n, "*%02X\n", bt_nmea_checksum(out, n));
  return n;
}

#endif
