"""One training triplet: sharp image, blurred image, heat maps (plus fit error and mask).

Order of operations for triplet ``(seed, index)`` (all randomness from one generator seeded by
``SeedSequence([seed, index])``, so a triplet never depends on which worker made it):
perturbation seed -> exposure -> gyro segment -> image crop -> saturation gain -> noise. The
perturbation draws from its own generator, seeded first whether or not it is used, so a
robustness dataset has exactly the sharp and blurred images of the clean one with that seed.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np

from blurtrack.errors import SynthesisError
from blurtrack.geometry.blur_model import BlurModel
from blurtrack.geometry.calibration import Calibration
from blurtrack.synth import photometry as ph
from blurtrack.synth.images import camera_for_size, fit_to_size
from blurtrack.synth.motion import GyroSource
from blurtrack.synth.paper import paper_model, paper_window, render_paper
from blurtrack.synth.perturb import Perturbation
from blurtrack.synth.render import RenderSettings, render_blur

MODES = ("exact", "paper")
#: Gyro coverage kept on each side of a segment (s); larger only for perturbed time shifts
#: beyond 6 sigma = 40 ms, so a robustness run blurs exactly like the unperturbed one.
SEGMENT_MARGIN_S = 0.05
#: Fit-error threshold of the reported share (px).
FIT_TOL_PX = 0.5
#: Draws of one triplet index tried before a ``min_blur_px`` it never reaches is an error.
MAX_DRAWS = 64


@dataclass(frozen=True)
class TripletParams:
    """Everything that shapes a triplet besides its inputs (stored in ``dataset.yaml``).

    ``readout_ms`` overrides the calibration's rolling-shutter readout (``None``: keep it).
    ``min_blur_px``: a draw whose median blur length (the manifest's ``blur_length_px.median``)
    is under it is discarded and the index drawn again (:func:`draw_triplet`); 0: off.
    """

    size: tuple[int, int] = (1280, 720)
    exposure_ms: tuple[float, float] = (10.0, 30.0)
    mode: str = "exact"
    photometry: ph.Photometry = field(default_factory=ph.Photometry)
    perturbation: Perturbation = field(default_factory=Perturbation)
    render: RenderSettings = field(default_factory=RenderSettings)
    heat_stride: int = 16
    heat_n_t: int = 16
    upscale: bool = True
    readout_ms: float | None = None
    min_blur_px: float = 0.0

    def __post_init__(self) -> None:
        size = tuple(int(v) for v in self.size)
        if len(size) != 2 or not (16 <= size[0] <= 8192 and 16 <= size[1] <= 8192):
            raise SynthesisError(f"size must be WxH with sides in [16, 8192], got {self.size}")
        exp = tuple(float(v) for v in self.exposure_ms)
        if len(exp) != 2 or not (
            all(math.isfinite(v) for v in exp) and 0 < exp[0] <= exp[1] <= 1000
        ):
            raise SynthesisError(
                f"exposure_ms must be a range 0 < lo <= hi <= 1000, got {self.exposure_ms}"
            )
        if self.mode not in MODES:
            raise SynthesisError(f"mode must be one of {MODES}, got {self.mode!r}")
        ph_ = self.photometry
        if self.mode == "paper" and (
            ph_.noise_shot or ph_.noise_read or ph_.jpeg_quality or ph_.saturation_gain > 1
        ):
            raise SynthesisError(
                "paper mode reproduces the source paper's synthesis: no noise, "
                "saturation or JPEG options"
            )
        if not 1 <= int(self.heat_stride) <= 64 or not 3 <= int(self.heat_n_t) <= 256:
            raise SynthesisError("heat_stride must be in [1, 64] and heat_n_t in [3, 256]")
        if self.readout_ms is not None and not (
            math.isfinite(self.readout_ms) and 0 <= self.readout_ms < 1000
        ):
            raise SynthesisError(f"readout_ms must be in [0, 1000), got {self.readout_ms}")
        if not (math.isfinite(self.min_blur_px) and 0 <= self.min_blur_px <= 10_000):
            raise SynthesisError(f"min_blur_px must be in [0, 10000], got {self.min_blur_px}")
        object.__setattr__(self, "size", size)
        object.__setattr__(self, "exposure_ms", exp)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["size"], d["exposure_ms"] = list(self.size), list(self.exposure_ms)
        if not self.min_blur_px:  # off: datasets made before the option keep their identity
            del d["min_blur_px"]
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TripletParams:
        try:
            d = dict(d)
            d["photometry"] = ph.Photometry(**d.get("photometry", {}))
            d["perturbation"] = Perturbation(**d.get("perturbation", {}))
            d["render"] = RenderSettings(**d.get("render", {}))
            return cls(**d)
        except TypeError as exc:
            raise SynthesisError(f"bad triplet parameters: {exc}") from None


@dataclass(frozen=True)
class Triplet:
    """``sharp``, ``blur`` uint8 ``(H, W, 3)``; ``heat`` float32 ``(6, H, W)``; ``fit_error``
    ``(H, W)`` px; ``valid (H, W)`` bool; ``info`` for the manifest."""

    sharp: np.ndarray
    blur: np.ndarray
    heat: np.ndarray
    fit_error: np.ndarray
    valid: np.ndarray
    info: dict[str, Any]


def triplet_rng(seed: int, index: int, draw: int = 0) -> np.random.Generator:
    """The generator of draw ``draw`` of triplet ``index``; draw 0 is ``[seed, index]``, so
    datasets without a minimum blur are unchanged by the redraw scheme."""
    key = [int(seed), int(index)] + ([int(draw)] if draw else [])
    return np.random.default_rng(np.random.SeedSequence(key))


def median_blur_length(heat: np.ndarray) -> float:
    """Median over pixels of ``|q(1) - q(0)|`` (px) of a ``(6, H, W)`` heat map."""
    return float(np.median(np.hypot(heat[2] - heat[0], heat[3] - heat[1])))


def make_triplet(
    image: np.ndarray,
    calib: Calibration,
    source: GyroSource,
    params: TripletParams,
    rng: np.random.Generator,
) -> Triplet:
    """Synthesise one triplet from an 8-bit BGR photograph (any size); ignores
    ``params.min_blur_px`` (one generator is one draw, see :func:`draw_triplet`)."""
    tr = _make_triplet(image, calib, source, params, rng, 0.0)
    assert tr is not None
    return tr


def draw_triplet(
    image: np.ndarray,
    calib: Calibration,
    source: GyroSource,
    params: TripletParams,
    seed: int,
    index: int,
) -> tuple[Triplet, int]:
    """Triplet ``index`` of a dataset seeded ``seed`` and the number of earlier draws that fell
    under ``params.min_blur_px`` (discarded before rendering, from their heat maps alone).
    Draw ``k`` uses :func:`triplet_rng` ``(seed, index, k)``: the result depends on the index
    only, never on the worker or the order of the build."""
    for draw in range(MAX_DRAWS):
        rng = triplet_rng(seed, index, draw)
        tr = _make_triplet(image, calib, source, params, rng, params.min_blur_px)
        if tr is not None:
            return tr, draw
    raise SynthesisError(
        f"the median blur stayed under min_blur_px={params.min_blur_px:g} in {MAX_DRAWS} "
        "draws (shake, exposure or focal length too small for it)"
    )


def _make_triplet(
    image: np.ndarray,
    calib: Calibration,
    source: GyroSource,
    params: TripletParams,
    rng: np.random.Generator,
    min_blur_px: float,
) -> Triplet | None:
    """One draw; ``None`` (before rendering) when its median blur is under ``min_blur_px``."""
    W, H = params.size
    cam = camera_for_size(calib.camera, W, H)
    if params.readout_ms is not None:
        cam = replace(cam, readout_s=params.readout_ms * 1e-3)
    calib_out = replace(calib, camera=cam)
    if not source.own_imu:  # a foreign trace: the calibrated IMU's shift and bias do not apply
        calib_out = replace(calib_out, timeshift_cam_imu_s=0.0, gyro_bias_radps=np.zeros(3))
    perturb_rng = np.random.default_rng(int(rng.integers(2**63)))
    exposure = float(rng.uniform(*params.exposure_ms)) * 1e-3
    margin = max(SEGMENT_MARGIN_S, params.perturbation.margin_s + 0.01)
    seg = source.segment(rng, cam.readout_s + exposure, margin, calib_out.timeshift_cam_imu_s)
    sharp8, fit = fit_to_size(image, W, H, rng, params.upscale)
    p = params.photometry
    gain = float(rng.uniform(1.0, p.saturation_gain)) if p.saturation_gain > 1 else 1.0
    if params.mode == "exact":
        model = BlurModel(calib_out, seg.trace)
        t_ref = model.default_reference_time(seg.frame_t_s, exposure)
        heat_frame_t, heat_calib = seg.frame_t_s, calib_out
    else:
        model = paper_model(calib_out, seg.trace)
        heat_frame_t = paper_window(calib_out, seg.frame_t_s)
        t_ref = heat_frame_t + exposure / 2
        heat_calib = model.calib
    drawn: dict[str, Any] = {}
    heat_model = model  # the blur's own model (its resampled gyro is reused) unless perturbed
    if params.perturbation.active:
        heat_calib, heat_trace, drawn = params.perturbation.apply(
            heat_calib, seg.trace, perturb_rng
        )
        heat_model = BlurModel(heat_calib, heat_trace, rotation_model=model.rotation_model)
    # Heat maps first (they use no draw of ``rng``): a draw under the minimum blur is
    # discarded before the costly rendering.
    heat, err = heat_model.heat_maps(
        heat_frame_t, exposure, params.heat_n_t, t_ref, params.heat_stride
    )
    if min_blur_px > 0 and median_blur_length(heat) < min_blur_px:
        return None
    if params.mode == "exact":
        lin = (
            ph.expand_saturation(ph.decode_srgb8(sharp8), p.saturation_threshold, gain)
            if p.linear
            else sharp8.astype(np.float32) / 255
        )
        res = render_blur(lin, model, seg.frame_t_s, exposure, t_ref, params.render)
        if gain > 1:
            sharp8 = ph.encode_srgb8(lin)
    else:
        res = render_paper(
            sharp8.astype(np.float32) / 255,
            calib_out,
            seg.trace,
            seg.frame_t_s,
            exposure,
            t_ref,
            params.render,
        )
    finish = p if params.mode == "exact" else ph.Photometry(linear=False)
    blur8 = ph.finish_blur(res.blur, finish, rng)
    length = np.hypot(heat[2] - heat[0], heat[3] - heat[1])
    info = {
        "exposure_s": exposure,
        "readout_s": cam.readout_s,
        "t_ref_s": t_ref,
        "intrinsics": list(cam.intrinsics),
        "gyro_segment": seg.info,
        "fit": fit,
        "saturation_gain": gain,
        "perturbation": drawn,
        "samples": int(res.tau.size),
        "max_step_px": res.max_step_px,
        "render_path": res.path,
        "valid_fraction": float(res.valid.mean()),
        "blur_length_px": {"median": float(np.median(length)), "max": float(length.max())},
        "bezier_fit": {
            "within_0.5px": float(np.mean(err <= FIT_TOL_PX)),
            "max_px": float(err.max()),
        },
    }
    return Triplet(sharp8, blur8, heat, err, res.valid, info)
