"""The SPECT side: reconstructed volumes in the SPECT frame, their readers, sphere centroids.

* :class:`Volume` (:mod:`.volume`) — data, voxel size, origin, axis directions, ``index_to_mm``;
* :func:`read_volume` / :func:`register_reader` (:mod:`.readers`) — Interfile 3.3, DICOM NM,
  ``.npz``, picked by extension then content;
* :func:`find_spheres` (:mod:`.spheres`) — centroids of the N hottest spheres, mm.
"""

from vts_hw.lazy import exports

# imported when first asked for: reading a list-mode file (spect.listmode) loads no volume reader
__getattr__ = exports(
    __name__,
    {
        **dict.fromkeys(["VolumeReader", "read_volume", "list_readers", "reader_for", "register_reader"], "readers"),
        **dict.fromkeys(["SphereResult", "SphereSettings", "find_spheres"], "spheres"),
        "Volume": "volume",
    },
)

__all__ = [
    "Volume",
    "VolumeReader",
    "read_volume",
    "reader_for",
    "list_readers",
    "register_reader",
    "SphereResult",
    "SphereSettings",
    "find_spheres",
]
