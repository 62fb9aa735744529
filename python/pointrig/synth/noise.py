"""Kinect-v1-like corruption of rendered depth images and point clouds.

Applied per frame in this order (each part has its own seeded random stream, so turning one
part off leaves the others' draws unchanged):

1. flying pixels at depth edges (mixed foreground/background depths along the ray);
2. axial noise ``sigma_z(z) = a + b (z - z0)^2`` metres with ``a = 0.0012, b = 0.0019,
   z0 = 0.4`` (Nguyen, Izadi, Lovell 2012, Eq. for the axial noise of Kinect v1);
3. disparity quantisation: ``d = f_q b_q / z`` rounded to ``1/8`` pixel (Kinect v1 baseline
   0.075 m, focal 580 px), so depth steps grow as ``z^2``;
4. random dropout of valid pixels, and dropout at grazing angles;
5. lateral jitter: pixel coordinates perturbed by ``N(0, lateral_px^2)`` before
   back-projection;
6. uniform outliers in the subject's bounding box enlarged by ``outlier_margin``.

Floor and background-wall geometry (``floor``, ``background``) are rendered with the subject
(they occlude and are occluded correctly) to test cropping.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np

from ..errors import ConfigError

__all__ = ["NoiseConfig", "axial_sigma", "apply_depth_noise", "outliers_in_box"]

# random stream ids, one per corruption
_S_FLY, _S_AXIAL, _S_DROP, _S_GRAZE, _S_LATERAL, _S_OUTLIER = range(1, 7)


@dataclass(frozen=True)
class NoiseConfig:
    """Kinect-like corruption settings (each part on/off and its magnitude; metres).

    ``NoiseConfig()`` is a moderate Kinect v1; ``NoiseConfig.clean()`` turns everything off.
    """

    seed: int = 0
    axial: bool = True
    axial_a: float = 0.0012  # Nguyen et al. 2012: sigma_z = a + b (z - z0)^2
    axial_b: float = 0.0019
    axial_z0: float = 0.4
    quantize: bool = True
    quant_subpixel: float = 0.125  # disparity step, pixels
    quant_baseline: float = 0.075  # Kinect v1 projector-camera baseline, metres
    quant_focal: float = 580.0  # Kinect v1 IR focal length, pixels
    lateral_px: float = 0.3  # lateral jitter std, pixels (0 = off)
    dropout: float = 0.02  # fraction of valid pixels dropped at random
    grazing_cos: float = 0.12  # |cos| of view angle below which pixels may drop (0 = off)
    flying: float = 0.5  # probability that an edge pixel becomes a flying pixel (0 = off)
    flying_jump: float = 0.05  # depth jump that makes an edge, metres
    flying_max: float = 0.3  # max flying offset behind an edge with no background, metres
    outliers: float = 0.005  # uniform outliers, fraction of the frame's points (0 = off)
    outlier_margin: float = 0.3  # box enlargement around the subject, metres
    floor: bool = False  # render a floor plane under the subject
    background: bool = False  # render a wall behind the subject
    background_distance: float = 1.0  # wall distance behind the subject's far side, metres

    @classmethod
    def clean(cls, **overrides) -> NoiseConfig:
        """No corruption at all (then ``overrides`` applied)."""
        return replace(cls(axial=False, quantize=False, lateral_px=0.0, dropout=0.0,
                           grazing_cos=0.0, flying=0.0, outliers=0.0), **overrides)

    @classmethod
    def kinect(cls, **overrides) -> NoiseConfig:
        """The default Kinect v1 model (then ``overrides`` applied)."""
        return replace(cls(), **overrides)

    def to_dict(self) -> dict:
        """Fields as a JSON-ready dict."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def validate(self) -> None:
        """Raise ``ValueError`` on out-of-range values."""
        for name in ("dropout", "flying", "grazing_cos"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise ConfigError(f"noise {name} must be in [0, 1], got {v}")
        for name in ("axial_a", "axial_b", "quant_subpixel", "quant_baseline", "quant_focal",
                     "lateral_px", "flying_jump", "flying_max", "outliers", "outlier_margin",
                     "background_distance"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ConfigError(f"noise {name} must be finite and >= 0, got {v}")


def _rng(cfg: NoiseConfig, frame: int, stream: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([int(cfg.seed), int(frame), stream]))


def axial_sigma(z: np.ndarray, cfg: NoiseConfig | None = None) -> np.ndarray:
    """Axial noise standard deviation at depth ``z`` metres (Nguyen et al. 2012)."""
    c = cfg or NoiseConfig()
    return c.axial_a + c.axial_b * (np.asarray(z) - c.axial_z0) ** 2


def quantize_depth(z: np.ndarray, cfg: NoiseConfig) -> np.ndarray:
    """Round depth to the Kinect disparity grid (``z > 0`` only)."""
    bf = cfg.quant_baseline * cfg.quant_focal
    out = z.copy()
    m = z > 0
    d = np.round(bf / z[m] / cfg.quant_subpixel) * cfg.quant_subpixel
    d = np.maximum(d, cfg.quant_subpixel)
    out[m] = bf / d
    return out


def _neighbour_stats(depth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel: max depth among valid 4-neighbours (0 if none) and whether any 4-neighbour is
    invalid (the image border counts as a copy of the edge pixels)."""
    pad = np.pad(depth, 1, mode="edge")
    nb = np.stack([pad[:-2, 1:-1], pad[2:, 1:-1], pad[1:-1, :-2], pad[1:-1, 2:]])
    return nb.max(axis=0), (nb <= 0).any(axis=0)


def apply_depth_noise(depth: np.ndarray, cos_view: np.ndarray | None, cfg: NoiseConfig,
                      frame: int) -> np.ndarray:
    """Corrupt a depth image ``(H, W)`` (metres, 0 = invalid); returns a new image.

    ``cos_view (H, W)`` is ``|cos|`` of the angle between the viewing ray and the surface normal
    (for grazing dropout), or ``None``.
    """
    d = depth.copy()
    valid = d > 0
    if cfg.flying > 0:
        nmax, has_hole = _neighbour_stats(depth)
        jump = nmax - depth
        edge = valid & (has_hole | (jump > cfg.flying_jump))
        rng = _rng(cfg, frame, _S_FLY)
        pick = edge & (rng.random(d.shape) < cfg.flying)
        gap = np.where(jump > cfg.flying_jump, jump, cfg.flying_max)
        d[pick] += rng.random(int(pick.sum())) * gap[pick]
    if cfg.axial:
        rng = _rng(cfg, frame, _S_AXIAL)
        z = d[valid]
        d[valid] = z + rng.standard_normal(z.shape) * axial_sigma(z, cfg)
    if cfg.quantize:
        d = quantize_depth(d, cfg)
    if cfg.dropout > 0:
        rng = _rng(cfg, frame, _S_DROP)
        d[valid & (rng.random(d.shape) < cfg.dropout)] = 0.0
    if cfg.grazing_cos > 0 and cos_view is not None:
        rng = _rng(cfg, frame, _S_GRAZE)
        p_drop = np.clip(1.0 - cos_view / cfg.grazing_cos, 0.0, 1.0)
        d[valid & (rng.random(d.shape) < p_drop)] = 0.0
    d[d < 0] = 0.0
    return d


def lateral_offsets(n: int, cfg: NoiseConfig, frame: int) -> tuple[np.ndarray, np.ndarray] | \
        tuple[None, None]:
    """Pixel offsets ``du, dv (n,)`` of the lateral jitter, or ``(None, None)`` if off."""
    if cfg.lateral_px <= 0:
        return None, None
    rng = _rng(cfg, frame, _S_LATERAL)
    off = rng.standard_normal((2, n)) * cfg.lateral_px
    return off[0], off[1]


def outliers_in_box(points: np.ndarray, cfg: NoiseConfig, frame: int) -> np.ndarray:
    """Uniform outliers ``(K, 3)`` in the bounding box of ``points`` enlarged by the margin;
    ``K = round(outliers * len(points))``."""
    k = int(round(cfg.outliers * len(points)))
    if k == 0 or len(points) == 0:
        return np.zeros((0, 3))
    rng = _rng(cfg, frame, _S_OUTLIER)
    lo = points.min(axis=0) - cfg.outlier_margin
    hi = points.max(axis=0) + cfg.outlier_margin
    lo[2] = max(lo[2], 0.3)
    return lo + rng.random((k, 3)) * (hi - lo)
