"""What the two cameras of the rig record, from a rendered Stokes cube, with their noise.

The noise-free captures are the observation model's (:func:`thinfilm.core.model.captures_from_stokes`).

``polarized_rgb``
    The polarization RGB camera: for each polarizer angle α the camera RGB
    (:mod:`thinfilm.core.colorimetry`) of I(α) = ½ (S0 + S1 cos 2α + S2 sin 2α) (Malus' law,
    :func:`thinfilm.core.conventions.malus_intensity`), then noise per image.
``spectral_s``, ``stokes_spectral``
    The hyperspectral camera with a rotating polarizer: for each band and each polarizer
    angle of the rig an image I(α), each with its own exposure and noise; the Stokes
    components are the least-squares fit to those images (for 0/45/90/135:
    S0 = ½ ΣI, S1 = I0 − I90, S2 = I45 − I135) and ``spectral_s`` = S0 + sqrt(S1² + S2²)
    (:func:`thinfilm.core.conventions.s_polarized`). With noise ``none`` both are exact.
"""

from __future__ import annotations

import numpy as np

from thinfilm.core.conventions import malus_intensity, stokes_design_matrix

from .noise import apply_camera_noise

__all__ = ["hyperspectral_capture"]


def hyperspectral_capture(stokes: dict, polarizer_angles_deg, mask, noise: dict, rngs) -> dict:
    """The hyperspectral camera behind a rotating polarizer: one noisy image per band and
    angle (``rngs``: one generator per angle), fitted to the measured Stokes cube.

    The least-squares Stokes fit (:func:`thinfilm.core.conventions.fit_stokes`) is
    accumulated one angle at a time so that only one noisy stack is held at once; up to two
    threads draw the noise (NumPy's generators release the GIL), within the process's thread
    budget (:mod:`thinfilm.core.threads`). Each angle has its own generator, so the result
    is the same with one thread or two.
    """
    from concurrent.futures import ThreadPoolExecutor

    from thinfilm.core.threads import thread_budget

    angles = [int(a) for a in polarizer_angles_deg]

    def shoot(i):
        image = malus_intensity(stokes["S0"], stokes["S1"], stokes["S2"], [angles[i]])[0]
        frames = np.moveaxis(image, -1, 0)  # (B, H, W) view
        return np.moveaxis(apply_camera_noise(frames, mask, noise, rngs[i]), 0, -1)

    fit = np.linalg.pinv(stokes_design_matrix(angles))  # (3, A)
    acc = np.zeros((3,) + stokes["S0"].shape)
    def accumulate(frames):
        for i, noisy in enumerate(frames):
            for s in range(3):
                acc[s] += fit[s, i] * noisy

    if thread_budget() < 2:
        accumulate(map(shoot, range(len(angles))))
    else:
        with ThreadPoolExecutor(max_workers=2) as pool:
            accumulate(pool.map(shoot, range(len(angles))))
    return {"S0": acc[0], "S1": acc[1], "S2": acc[2]}
