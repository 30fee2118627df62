"""Writes the two NumPy archives here: `amass_savez.npz` (np.savez: entries stored) and
`amass_savez_compressed.npz` (np.savez_compressed: deflated), with the arrays of an AMASS
file (SMPL-H poses, translation, frame rate, shape). Their values follow formulas that
`tests/it/numpy_archives.rs` recomputes. Written with NumPy 2.4.6:
    python make.py
"""
import numpy as np

n = 4
i = np.arange(n * 156, dtype=np.float64).reshape(n, 156)
poses = 0.3 * np.sin(0.01 * i)
trans = (0.1 * np.arange(n * 3, dtype=np.float64).reshape(n, 3)).astype(np.float32)
betas = np.linspace(-1.0, 1.0, 16)
arrays = dict(poses=poses, trans=trans, mocap_framerate=np.array(60.0), betas=betas,
              gender=np.array("neutral"))
np.savez("amass_savez.npz", **arrays)
np.savez_compressed("amass_savez_compressed.npz", **arrays)
