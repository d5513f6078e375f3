"""A self-signed certificate for simulated HTTPS cameras on 127.0.0.1 (made with the openssl CLI).

The certificate names ``127.0.0.1`` and ``localhost`` (subjectAltName), so a client that is
told to trust it (``ca_cert:`` in rig.yaml, ``verify=`` in requests) checks the host name as
it would for a real camera. The key is written with mode 600 (:func:`self_signed`).
"""

from __future__ import annotations

import shutil
import subprocess
import tempfile
from pathlib import Path

from vts_hw.errors import VtsError
from vts_hw.files import check_target, ensure_dir, write_atomic, write_secret
from vts_hw.lifeline import child_options

CERT_NAME, KEY_NAME = "sim-camera-cert.pem", "sim-camera-key.pem"


def self_signed(folder: str | Path, days: int = 30) -> tuple[Path, Path]:
    """Write ``sim-camera-cert.pem`` and ``sim-camera-key.pem`` into ``folder``; return both paths.
    openssl writes them into a private temporary folder (0700): the key is never readable by
    anyone else, not even while openssl writes it; they are then written whole beside rig.yaml,
    the key 0600 (files.write_secret), neither over a device, FIFO or symbolic link."""
    openssl = shutil.which("openssl")
    if openssl is None:
        raise VtsError("a simulated HTTPS camera needs the openssl command (apt-get install openssl)")
    folder = ensure_dir(folder, "simulated rig folder")
    cert, key = folder / CERT_NAME, folder / KEY_NAME
    check_target(cert)
    check_target(key)
    with tempfile.TemporaryDirectory(prefix="vts-sim-tls-") as work:
        made_cert, made_key = Path(work) / CERT_NAME, Path(work) / KEY_NAME
        cmd = [
            openssl,
            "req",
            "-x509",
            "-newkey",
            "ec",
            "-pkeyopt",
            "ec_paramgen_curve:prime256v1",
            "-nodes",
            "-keyout",
            str(made_key),
            "-out",
            str(made_cert),
            "-days",
            str(days),
            "-subj",
            "/O=vts-hw simulated rig/CN=127.0.0.1",
            "-addext",
            "subjectAltName=IP:127.0.0.1,DNS:localhost",
            "-addext",
            "basicConstraints=critical,CA:TRUE",
        ]
        done = subprocess.run(cmd, capture_output=True, text=True, **child_options())
        if done.returncode != 0:
            raise VtsError(f"openssl could not make the simulated cameras' certificate: {done.stderr.strip()[-200:]}")
        write_secret(key, made_key.read_bytes())
        write_atomic(cert, made_cert.read_bytes())
    return cert, key
