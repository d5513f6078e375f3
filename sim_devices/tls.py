"""A self-signed certificate for simulated HTTPS cameras on 127.0.0.1 (made with the openssl CLI).

The certificate names ``127.0.0.1`` and ``localhost`` (subjectAltName), so a client that is
told to trust it (``ca_cert:`` in rig.yaml, ``verify=`` in requests) checks the host name as
it would for a real camera. The key is written with mode 600.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

from vts_hw.errors import VtsError

CERT_NAME, KEY_NAME = "sim-camera-cert.pem", "sim-camera-key.pem"


def self_signed(folder: str | Path, days: int = 30) -> tuple[Path, Path]:
    """Write ``sim-camera-cert.pem`` and ``sim-camera-key.pem`` into ``folder``; return both paths."""
    openssl = shutil.which("openssl")
    if openssl is None:
        raise VtsError("a simulated HTTPS camera needs the openssl command (apt-get install openssl)")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    cert, key = folder / CERT_NAME, folder / KEY_NAME
    cmd = [openssl, "req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes",
           "-keyout", str(key), "-out", str(cert), "-days", str(days), "-subj", "/O=vts-hw simulated rig/CN=127.0.0.1",
           "-addext", "subjectAltName=IP:127.0.0.1,DNS:localhost",
           "-addext", "basicConstraints=critical,CA:TRUE"]
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0:
        raise VtsError(f"openssl could not make the simulated cameras' certificate: {done.stderr.strip()[-200:]}")
    os.chmod(key, 0o600)
    return cert, key
