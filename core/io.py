"""Dataset, estimate and evaluation folders: the one place that reads and writes them.

This module gathers the public names of the modules that do the work, so that
``thinfilm.core.io.read_dataset`` and the rest keep one address:

:mod:`~thinfilm.core.exr`
    Channel names, :func:`read_exr`, :func:`write_exr`, :func:`set_exr_threads`.
:mod:`~thinfilm.core.files`
    Text, TOML and JSON readers, :func:`write_json`, :func:`read_mask_file`.
:mod:`~thinfilm.core.dataset`
    Dataset folders, format ``thinfilm-dataset/1`` (``docs/design.md``, *Dataset folder*):
    :class:`Dataset`, :func:`read_dataset`, :func:`write_dataset`, :func:`dataset_meta`.
:mod:`~thinfilm.core.estimate`
    Estimate folders (``docs/design.md``, *Estimate folder*): :class:`Estimate`,
    :func:`write_estimate`, :func:`read_estimate`, :func:`height_to_mesh`.
:mod:`~thinfilm.core.evaluation_files`
    Evaluation folders: :func:`write_evaluation_files`, :func:`read_metrics`.

Readers stop with a :class:`~thinfilm.core.errors.UserError` that names the file and the
channel when a file is missing or damaged, a channel is missing, shapes disagree, captures
hold NaN, or the ``format`` is unknown. Writers write into a folder that exists (see
:mod:`thinfilm.core.outputs` for safe output folders); files are deterministic (same arrays,
same bytes).

Examples
--------
>>> pol_layer(45), band_channel(7)
('pol045', 'band007')
"""

from __future__ import annotations

from .dataset import (FORMAT, GROUND_TRUTH_CHANNELS, POLARIZER_NOT_CORRECTED, Dataset, check_polarizer_calibration,
                      dataset_meta, read_dataset, software_versions, write_dataset)
from .estimate import (ESTIMATE_CHANNELS, ESTIMATE_FORMAT, SIGMA_CHANNELS, Estimate, height_to_mesh, read_estimate,
                       write_estimate)
from .evaluation_files import read_metrics, write_evaluation_files
from .exr import (band_channel, band_channels, pol_layer, polarized_rgb_channels, read_exr, set_exr_threads,
                  write_exr)
from .files import parse_json_text, read_json, read_text_file, read_toml, write_json
from .masks import read_mask_file

__all__ = [
    "FORMAT",
    "GROUND_TRUTH_CHANNELS",
    "POLARIZER_NOT_CORRECTED",
    "check_polarizer_calibration",
    "ESTIMATE_CHANNELS",
    "ESTIMATE_FORMAT",
    "Dataset",
    "Estimate",
    "SIGMA_CHANNELS",
    "read_exr",
    "write_exr",
    "set_exr_threads",
    "read_dataset",
    "write_dataset",
    "dataset_meta",
    "software_versions",
    "read_estimate",
    "write_estimate",
    "write_evaluation_files",
    "read_metrics",
    "height_to_mesh",
    "read_json",
    "parse_json_text",
    "read_text_file",
    "read_toml",
    "read_mask_file",
    "write_json",
    "pol_layer",
    "band_channel",
    "polarized_rgb_channels",
    "band_channels",
]
