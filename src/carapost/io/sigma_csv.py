"""Per-sample uncertainty sidecar: ``<export>.sigma.csv`` beside a C3D export.

One row per exported point-frame that has a 3D sample::

    frame,label,x_mm,y_mm,z_mm,sigma_mm,recon
    1,P001,12.503100,-40.117000,88.200400,0.0712,triangulated

``frame`` is the burnt-in frame number (index + 1, as in the C3D), ``sigma_mm`` the
estimated standard deviation of the sample's 3D error (empty where unknown) and
``recon`` how the sample was made (``RECON_NAMES``). Written atomically.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from carapost.algorithms.codes import RECON_NAMES
from carapost.io.atomic import atomic_write_bytes

__all__ = ["sidecar_path", "write_sigma_csv"]


def sidecar_path(export_path: str | Path) -> Path:
    """The sidecar of an export: ``take.c3d`` -> ``take.sigma.csv``.

    Examples
    --------
    >>> sidecar_path("out/take.c3d").as_posix()
    'out/take.sigma.csv'
    """
    p = Path(export_path)
    return p.with_name(p.stem + ".sigma.csv")


def write_sigma_csv(path: str | Path, positions: ArrayLike, sigma: ArrayLike,
                    recon: ArrayLike, labels: list[str], first_frame: int = 1) -> Path:
    """Write the sidecar CSV (see the module docstring).

    Parameters
    ----------
    path : str or Path
    positions : array_like, shape (F, P, 3)
        mm, NaN where no sample.
    sigma : array_like, shape (F, P)
        mm, NaN where unknown.
    recon : array_like, shape (F, P) int
    labels : list of str, length P
    first_frame : int
        Frame number of row 0.

    Returns
    -------
    Path
    """
    X = np.asarray(positions, dtype=np.float64)
    s = np.asarray(sigma, dtype=np.float64)
    rc = np.asarray(recon)
    fi, pi = np.nonzero(np.isfinite(X).all(-1))
    buf = io.StringIO()
    buf.write("frame,label,x_mm,y_mm,z_mm,sigma_mm,recon\n")
    names = {int(k): v for k, v in RECON_NAMES.items()}
    for f, p in zip(fi.tolist(), pi.tolist(), strict=True):
        x, y, z = X[f, p]
        sg = s[f, p]
        buf.write(f"{f + first_frame},{labels[p]},{x:.6f},{y:.6f},{z:.6f},"
                  f"{'' if not np.isfinite(sg) else f'{sg:.4f}'},"
                  f"{names.get(int(rc[f, p]), str(int(rc[f, p])))}\n")
    out = Path(path)
    atomic_write_bytes(out, buf.getvalue().encode())
    return out
