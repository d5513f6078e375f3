"""Which frame a SPECT-frame position is in, said exactly (docs/design.md, "SPECT frame").

The **SPECT frame**: millimetres, right-handed, X towards the patient's left, Y towards the
patient's anterior (up for a supine patient), Z towards the patient's feet. It is *placed* by the
volume the VTS -> SPECT mapping was made from (the mapping fits the phantom's spheres as that
volume gives them), so its origin is that volume's:

* **DICOM NM**: the DICOM patient-coordinate origin (wherever the scanner puts it; often not the
  field of view's centre); the axes are DICOM's LPS axes turned (``dicom_nm.PATIENT_TO_SPECT``:
  X = x_L, Y = -y_P, Z = -z_S), exact for any patient position because LPS is the patient's own.
* **Interfile**: ``first pixel offset (mm)`` places the first voxel (without it the volume is
  centred on the origin); matrix [1], [2], [3] run along +X, -Y, +Z -- a transaxial slice as it is
  displayed (columns from the patient's right to left, rows from anterior to posterior), slices
  from head to feet. A CASToR-written Interfile (its ``CASToR version`` key) is read in CASToR's
  own frame instead (``interfile.py``). Interfile carries no trustworthy patient orientation, so
  the patient directions above hold when the volume is laid out that way.
* **npz**: the file's own ``origin`` and ``direction``.

:func:`volume_record` is what a mapping keeps of that volume (its file, format, centre in the
SPECT frame, patient position when the file says it): enough to carry a pose into another
program's image frame later (``vts_hw.motion.castor``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vts_hw.spect.interfile import written_by_castor
from vts_hw.spect.readers import reader_for

__all__ = ["SPECT_FRAME", "VTS_FRAME", "VTS_AXES", "volume_record", "frame_description"]

SPECT_FRAME = (
    "SPECT frame: mm, right-handed; X towards the patient's left, Y towards the patient's "
    "anterior (up for a supine patient), Z towards the patient's feet; origin where the volume "
    "the VTS -> SPECT mapping was made from puts it (DICOM NM: the patient-coordinate origin; "
    "Interfile: by its first pixel offset, else the volume's centre; npz: its origin)"
)
VTS_AXES = (
    "VTS frame: camera 1's, mm, right-handed (OpenCV: x right and y down in its image, z along "
    "its optical axis, origin at its optical centre)"
)
VTS_FRAME = VTS_AXES + "; no VTS -> SPECT mapping was given"


def volume_record(path, volume, fmt: str | None = None) -> dict:
    """What a mapping keeps of the volume it was made from: file name, reader, shape, voxel
    size, the SPECT-frame position of the **centre of its matrix** (where a reconstruction's
    field of view is centred), and, for DICOM, ``PatientPosition`` (``HFS`` ...) when the file
    has it (else None)."""
    path = Path(path)
    if fmt is None:
        fmt = reader_for(path).name
    centre = volume.index_to_mm((np.asarray(volume.data.shape, float) - 1) / 2)
    rec = {
        "file": path.name,
        "format": fmt,
        "shape": [int(n) for n in volume.data.shape],
        "voxel_size_mm": [float(v) for v in volume.voxel_size],
        "centre_mm": [round(float(v), 6) for v in centre],
        "patient_position": None,
        "castor_image": False,
    }
    if fmt == "dicom":
        rec["patient_position"] = _dicom_patient_position(path)
    elif fmt == "interfile":
        rec["castor_image"] = written_by_castor(path)
    return rec


def _dicom_patient_position(path: Path) -> str | None:
    try:
        import pydicom

        ds = pydicom.dcmread(path, stop_before_pixels=True)
        value = ds.get("PatientPosition")
    except Exception:  # noqa: BLE001 - the volume was read already; this is only a label
        return None
    text = str(value).strip().upper() if value else ""
    return text or None


def frame_description(frame: str, volume: dict | None = None) -> dict:
    """The ``frame`` of a JSON output: its name, its definition, and the volume that places it
    (SPECT frame) when known."""
    if frame == "spect":
        return {"name": "SPECT frame", "definition": SPECT_FRAME, "volume": volume}
    return {"name": "VTS frame", "definition": VTS_FRAME, "volume": None}
