"""Evaluation folders: ``metrics.json``, ``evaluation.json``, ``rerendered.exr`` and
``errors.exr`` (``docs/design.md``, *Evaluation output*)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .errors import UserError
from .exr import band_channels, polarized_rgb_channels, write_exr
from .files import read_json, write_json

__all__ = ["write_evaluation_files", "read_metrics"]


def write_evaluation_files(folder, metrics: dict, info: dict, rerendered_polarized_rgb: dict, rerendered_spectral_s,
                           error_maps: dict, mask) -> Path:
    """Write the files of an evaluation folder into ``folder`` (which exists): ``metrics.json``,
    ``evaluation.json``, ``rerendered.exr`` (the re-rendered captures: ``pol000.R`` …,
    ``spectral_s.band000`` …) and ``errors.exr`` (error maps, NaN stored as 0, and ``mask``)."""
    folder = Path(folder)
    write_json(folder / "metrics.json", metrics)
    write_json(folder / "evaluation.json", info)
    write_exr(folder / "rerendered.exr", {**polarized_rgb_channels(rerendered_polarized_rgb),
                                          **band_channels(np.asarray(rerendered_spectral_s), "spectral_s.")})
    write_exr(folder / "errors.exr", {**{k: np.nan_to_num(v, nan=0.0) for k, v in error_maps.items()},
                                      "mask": np.asarray(mask).astype(np.float32)})
    return folder


def read_metrics(folder) -> dict:
    """``metrics.json`` of an evaluation folder."""
    metrics = read_json(Path(folder) / "metrics.json", missing="not a thinfilm evaluation folder")
    if not isinstance(metrics, dict):
        raise UserError(f"{Path(folder) / 'metrics.json'}: expected a JSON object")
    return metrics
