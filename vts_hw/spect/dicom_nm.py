"""DICOM NM reconstructed volumes (one multi-frame NM object), via pydicom (imported lazily).

Geometry, as in the DICOM NM Image IOD for ``RECON TOMO`` images:

* frames are slices; ``ImagePositionPatient`` (IPP) is the centre of the first voxel of frame 1
  and ``ImageOrientationPatient`` (IOP) the row and column direction cosines, read at the top
  level or in the first item of the Detector Information Sequence (where NM puts them);
* ``PixelSpacing`` = (spacing between rows, between columns); the slice step is
  ``SpacingBetweenSlices`` (else ``SliceThickness``) along ``row × column`` from IPP;
* ``RescaleSlope``/``RescaleIntercept`` are applied when present.

Patient → SPECT axes: DICOM's LPS patient axes map as ``X = x_L`` (the patient's left),
``Y = −y_P`` (anterior: up for a supine patient), ``Z = −z_S`` (towards the feet: for a head-first
patient, out of the gantry towards the foot of the table), a 180° rotation about x; both frames
are right-handed. The origin stays DICOM's patient-coordinate origin (wherever the scanner puts
it: not necessarily the FOV centre; ``vts_hw.spect.frame``). ``PATIENT_TO_SPECT`` holds it; pass
another matrix to the reader and writer for another set-up.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from vts_hw.errors import DataError
from vts_hw.spect.volume import Volume

PATIENT_TO_SPECT = np.diag([1.0, -1.0, -1.0])  # spect = M @ patient
NM_IMAGE_STORAGE = "1.2.840.10008.5.1.4.1.1.20"


def _pydicom():
    try:
        import pydicom
    except ImportError:  # pragma: no cover - pydicom is a declared dependency
        raise DataError("reading DICOM needs pydicom (pip install 'pydicom>=2.4')") from None
    return pydicom


def _geometry_item(ds):
    from pydicom.dataset import Dataset

    if "ImagePositionPatient" in ds and "ImageOrientationPatient" in ds:
        return ds
    seq = ds.get("DetectorInformationSequence")
    item = seq[0] if isinstance(seq, Sequence) and len(seq) else None
    if isinstance(item, Dataset) and "ImagePositionPatient" in item and "ImageOrientationPatient" in item:
        return item
    return None


def _decode_all(ds, path: Path) -> None:
    """Decode every element now: pydicom decodes lazily, on first access, and a corrupt element
    (unknown VR, wrong length, a sequence cut short) raises whatever its decoder raises."""
    tag = None
    try:
        for elem in ds.iterall():
            tag = elem.tag
    except Exception as e:  # noqa: BLE001 - pydicom's decoders raise many kinds; none is documented
        after = f" after element {tag}" if tag is not None else ""
        raise DataError(
            f"{path}: a corrupt DICOM data element{after} ({type(e).__name__}: {' '.join(str(e).split())[:120]})"
        ) from None


def _numbers(path: Path, ds, key: str, n: int) -> list[float]:
    """``n`` finite numbers from element ``key``; DataError naming the file and the key."""
    value = ds.get(key)
    values = list(value) if isinstance(value, Sequence) and not isinstance(value, (str, bytes)) else [value]
    try:
        out = [float(v) for v in values]
    except (TypeError, ValueError, OverflowError):
        out = []
    if len(out) != n or not all(math.isfinite(v) for v in out):
        raise DataError(f"{path}: DICOM {key} is {repr(value)[:60]}, not {n} finite number{'s' * (n > 1)}")
    return out


def _count(path: Path, ds, key: str) -> int:
    """A positive whole number from element ``key`` (Rows, Columns, NumberOfFrames)."""
    (v,) = _numbers(path, ds, key, 1)
    if v != int(v) or v < 1:
        raise DataError(f"{path}: DICOM {key} is {v:g}, not a positive whole number")
    return int(v)


def read_dicom_nm(path, patient_to_spect=PATIENT_TO_SPECT) -> Volume:
    """Read a multi-frame DICOM NM reconstruction; returns the canonical :class:`Volume`."""
    pydicom = _pydicom()
    path = Path(path)
    try:
        ds = pydicom.dcmread(path)
    except pydicom.errors.InvalidDicomError:
        raise DataError(f"{path}: not a DICOM file (no DICM preamble)") from None
    except OSError as e:
        raise DataError(f"{path}: cannot read ({e.strerror or e})") from None
    except Exception as e:  # truncated or corrupt data elements
        raise DataError(f"{path}: unreadable DICOM ({type(e).__name__}: {e})") from None
    _decode_all(ds, path)
    modality = ds.get("Modality", None)
    if modality != "NM":
        raise DataError(f"{path}: not a DICOM NM image (Modality is {modality or 'missing'})")
    for key in ("PixelSpacing", "PixelData", "Rows", "Columns"):
        if key not in ds:
            raise DataError(f"{path}: DICOM NM without {key}")
    geo = _geometry_item(ds)
    if geo is None:
        raise DataError(f"{path}: DICOM NM without ImagePositionPatient/ImageOrientationPatient")
    step_key = "SpacingBetweenSlices" if ds.get("SpacingBetweenSlices") else "SliceThickness"
    if not ds.get(step_key):
        raise DataError(f"{path}: DICOM NM without SpacingBetweenSlices or SliceThickness")
    (step,) = _numbers(path, ds, step_key, 1)
    rows, cols = _count(path, ds, "Rows"), _count(path, ds, "Columns")
    frames = _count(path, ds, "NumberOfFrames") if ds.get("NumberOfFrames") else 1
    dr, dc = _numbers(path, ds, "PixelSpacing", 2)
    slope = _numbers(path, ds, "RescaleSlope", 1)[0] if ds.get("RescaleSlope") else 1.0
    intercept = _numbers(path, ds, "RescaleIntercept", 1)[0] if ds.get("RescaleIntercept") else 0.0
    iop = np.asarray(_numbers(path, geo, "ImageOrientationPatient", 6))
    ipp = np.asarray(_numbers(path, geo, "ImagePositionPatient", 3))
    try:
        arr = ds.pixel_array
    except Exception as e:
        raise DataError(f"{path}: DICOM pixel data unreadable ({e})") from None
    if arr.ndim == 2:
        arr = arr[None]
    if arr.shape != (frames, rows, cols):
        raise DataError(f"{path}: pixel data shape {arr.shape} does not match {frames} frames of {rows}×{cols}")
    data = arr.astype(np.float32) * np.float32(slope) + np.float32(intercept)
    row_cos, col_cos = iop[:3], iop[3:]
    normal = np.cross(row_cos, col_cos)
    m = np.asarray(patient_to_spect, dtype=float)
    # array axes: 0 = frames (along the normal), 1 = rows (along col_cos), 2 = columns (row_cos)
    direction = np.stack([m @ normal, m @ col_cos, m @ row_cos])
    origin = m @ ipp
    try:
        vol = Volume(data, (step, dr, dc), origin, direction, path)
        return vol.canonical()
    except ValueError as e:
        raise DataError(f"{path}: unusable DICOM geometry ({e})") from None


def write_dicom_nm(volume: Volume, path, patient_to_spect=PATIENT_TO_SPECT) -> Path:
    """Write ``volume`` as a minimal multi-frame NM ``RECON TOMO`` object (16-bit, rescaled).

    Slices are written as standard transaxial images (IOP ``1,0,0,0,1,0`` under the default
    mapping: rows run from anterior to posterior, frames from the feet to the head).
    """
    _pydicom()  # one sentence when pydicom is missing
    from pydicom.dataset import Dataset, FileMetaDataset
    from pydicom.sequence import Sequence
    from pydicom.tag import Tag
    from pydicom.uid import UID, ExplicitVRLittleEndian, generate_uid

    path = Path(path)
    m = np.asarray(patient_to_spect, dtype=float)
    # choose array layout (frames, rows, cols) with patient directions +z, +y, +x
    spect_dirs = np.stack([m @ e for e in np.eye(3)[::-1]])  # rows: patient z, y, x in SPECT
    v = volume.canonical()
    vol = Volume(v.data, v.voxel_size, v.origin, v.direction)
    # re-express: for each target axis find the canonical axis and sign
    order, flips = [], []
    for d in spect_dirs:
        dots = vol.direction @ d
        a = int(np.argmax(np.abs(dots)))
        order.append(a)
        flips.append(dots[a] < 0)
    data = np.transpose(vol.data, order)
    first = np.zeros(3)
    for new_axis, (a, flip) in enumerate(zip(order, flips)):
        if flip:
            data = np.flip(data, axis=new_axis)
            first[a] = vol.data.shape[a] - 1
    ipp = m.T @ vol.index_to_mm(first)
    step, dr, dc = (vol.voxel_size[a] for a in order)

    data = np.asarray(data, dtype=float)
    lo = min(0.0, float(data.min()))
    span = float(data.max()) - lo
    integral = np.allclose(data, np.rint(data)) and lo == 0 and span <= 65535
    slope = 1.0 if integral or span == 0 else span / 65535.0
    pixels = np.clip(np.rint((data - lo) / slope), 0, 65535).astype("<u2")

    sop_uid = generate_uid()
    meta = FileMetaDataset()
    meta.MediaStorageSOPClassUID = UID(NM_IMAGE_STORAGE)
    meta.MediaStorageSOPInstanceUID = sop_uid
    meta.TransferSyntaxUID = ExplicitVRLittleEndian
    ds = Dataset()
    ds.file_meta = meta
    ds.SOPClassUID = NM_IMAGE_STORAGE
    ds.SOPInstanceUID = sop_uid
    ds.StudyInstanceUID = generate_uid()
    ds.SeriesInstanceUID = generate_uid()
    ds.FrameOfReferenceUID = generate_uid()
    ds.Modality = "NM"
    ds.ImageType = ["ORIGINAL", "PRIMARY", "RECON TOMO", "EMISSION"]
    ds.PatientName = "PHANTOM^7SPHERE"
    ds.PatientID = "VTS-QA"
    ds.PatientPosition = "HFS"
    ds.SeriesNumber = 1
    ds.InstanceNumber = 1
    nf, nr, nc = pixels.shape
    ds.NumberOfFrames = nf
    ds.FrameIncrementPointer = Tag(0x0054, 0x0080)  # Slice Vector
    ds.SliceVector = list(range(1, nf + 1))
    ds.NumberOfSlices = nf
    ds.Rows, ds.Columns = nr, nc
    ds.SamplesPerPixel = 1
    ds.PhotometricInterpretation = "MONOCHROME2"
    ds.BitsAllocated, ds.BitsStored, ds.HighBit, ds.PixelRepresentation = 16, 16, 15, 0
    ds.PixelSpacing = [f"{dr:.6g}", f"{dc:.6g}"]
    ds.SliceThickness = f"{step:.6g}"
    ds.SpacingBetweenSlices = f"{step:.6g}"
    ds.RescaleSlope = f"{slope:.10g}"
    ds.RescaleIntercept = f"{lo:.10g}"
    det = Dataset()
    det.ImagePositionPatient = [f"{x:.6f}" for x in ipp]
    det.ImageOrientationPatient = ["1", "0", "0", "0", "1", "0"]
    ds.DetectorInformationSequence = Sequence([det])
    ds.PixelData = pixels.tobytes()
    try:
        ds.save_as(path, enforce_file_format=True)  # pydicom >= 3
    except TypeError:  # pragma: no cover - pydicom 2.x
        ds.is_little_endian, ds.is_implicit_VR = True, False
        ds.save_as(path, write_like_original=False)
    return path
