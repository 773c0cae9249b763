"""C3D export and import (our own numpy reader and writer).

Why our own code instead of ezc3d or py-c3d (details in docs/file-formats.md):

* ezc3d 1.7.2 swaps the two bytes of the fourth point word relative to the C3D spec and
  always writes a header scale of -1.0, so its residuals and camera masks are wrong in any
  spec-following reader; its Python objects also cost ~2 GB for a 10-minute take.
* py-c3d follows the spec but builds one Python object per frame and has no LABELS2 support.
* The data block is a plain array of little-endian float32, so numpy writes it in chunks at
  disk speed, and a pure-Python parameter parser cannot crash the process on a bad file.

Word 4 of every point sample is written exactly as the spec says: a signed 16-bit integer
stored as a float, residual byte (``residual / |POINT:SCALE|``) in the low byte, the
contribution mask of cameras 1-7 in bits 8-14 of the high byte, ``-1`` for invalid samples.
Samples marked *modified* (interpolated, filtered, ...) get word 4 = 0, which the spec
defines as "valid but processed" (mask cleared, residual 0). A measured sample always gets a
residual byte of at least 1 so that it is not mistaken for a processed one.

With more than 7 cameras the whole contribution mask is stored in extra analog channels at
the point rate (one channel per point, value = uint16 bit mask, bit c = camera c + 1), and the
``CARAPOST`` parameter group says so (``MASK_LAYOUT = "WORD4+ANALOG"``). Parameters cannot
hold it: a parameter is limited to 32 KB and the whole parameter section to 255 blocks.

The package: ``_format`` (block and type codes, `C3DData`), ``_params`` (the parameter
section), ``_write`` (`write_c3d`, `choose_residual_scale`) and ``_read`` (`read_c3d`).
"""

from __future__ import annotations

from carapost.io.c3d._format import C3DData
from carapost.io.c3d._read import read_c3d
from carapost.io.c3d._write import choose_residual_scale, write_c3d

__all__ = ["C3DData", "read_c3d", "write_c3d", "choose_residual_scale"]
