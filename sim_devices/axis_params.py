"""The parameter tree of a simulated Axis camera (``param.cgi``): values, groups, updates."""

from __future__ import annotations

import threading

DEFAULT_FPS = 25
MAX_FPS = 30
DEFAULT_COMPRESSION = 25
PRODUCT_NUMBER = "P1344"


class ParamStore:
    """The camera's parameter tree (``root.X.Y=Z``), in memory, safe between threads."""

    READ_ONLY = ("root.Brand.", "root.Properties.")

    def __init__(self, values: dict[str, str], resolutions: list[str]):
        self._values = dict(values)
        self._resolutions = resolutions
        self._lock = threading.Lock()

    @staticmethod
    def _full(name: str) -> str:
        name = name.strip()
        return name if name.startswith("root.") or name == "root" else "root." + name

    def get(self, name: str) -> str:
        with self._lock:
            return self._values[self._full(name)]

    def list(self, groups: str | None) -> str:
        """The body of ``action=list``: matching lines, and an error line per unknown group."""
        names = [g for g in (groups or "root").split(",") if g.strip()] or ["root"]
        out: list[str] = []
        with self._lock:
            for group in names:
                full = self._full(group)
                hits = [k for k in self._values if k == full or k.startswith(full + ".") or full == "root"]
                if hits:
                    out += [f"{k}={self._values[k]}" for k in hits]
                else:
                    out.append(f"# Error: Error -1 getting param in group '{group.strip()}'")
        return "".join(line + "\r\n" for line in out)

    def update(self, changes: list[tuple[str, str]]) -> str:
        """The body of ``action=update``: ``OK`` or the first error; nothing changes on error."""
        checked: list[tuple[str, str]] = []
        with self._lock:
            for name, value in changes:
                full = self._full(name)
                if full not in self._values or full.startswith(self.READ_ONLY) or not self._valid(full, value):
                    return f"# Error: Error setting '{full}' to '{value}'!\r\n"
                checked.append((full, value))
            self._values.update(checked)
        return "OK\r\n"

    def _valid(self, full: str, value: str) -> bool:
        if full.endswith(".Appearance.Compression"):
            return value.isdigit() and 0 <= int(value) <= 100
        if full.endswith(".Stream.FPS"):
            return value.isdigit() and int(value) <= MAX_FPS
        if full.endswith(".Appearance.Resolution"):
            return value in self._resolutions
        return True


def default_params(source, firmware: str, resolutions: list[str]) -> dict[str, str]:
    product = source.product
    serial = product.mac.hex().upper()
    return {
        "root.Brand.Brand": "AXIS",
        "root.Brand.ProdFullName": f"AXIS {PRODUCT_NUMBER} Network Camera",
        "root.Brand.ProdNbr": PRODUCT_NUMBER,
        "root.Brand.ProdShortName": f"AXIS {PRODUCT_NUMBER}",
        "root.Brand.ProdType": "Network Camera",
        "root.Brand.ProdVariant": "",
        "root.Brand.WebURL": "http://www.axis.com",
        "root.Properties.API.HTTP.Version": "3" if firmware == "vapix3" else "2",
        "root.Properties.Firmware.Version": product.firmware_str,
        "root.Properties.Firmware.BuildDate": "Jan 01 2020 00:00",
        "root.Properties.Image.Format": "jpeg,mjpeg",
        "root.Properties.Image.Resolution": ",".join(resolutions),
        "root.Properties.System.HardwareID": format(product.hardware_id, "X"),
        "root.Properties.System.SerialNumber": serial,
        "root.Image.I0.Name": source.name,
        "root.Image.I0.Appearance.Resolution": resolutions[0],
        "root.Image.I0.Appearance.Compression": str(DEFAULT_COMPRESSION),
        "root.Image.I0.Stream.FPS": str(DEFAULT_FPS),
        "root.IOPort.I0.Configurable": "no",
        "root.IOPort.I0.Direction": "output",
        "root.IOPort.I0.Output.Name": "LED ring",
        "root.IOPort.I0.Output.Active": "closed",
        "root.IOPort.I0.Output.Button": "none",
        "root.IOPort.I0.Output.PulseTime": "0",
        "root.Network.eth0.MACAddress": product.mac_str,
        "root.Time.SyncSource": "NTP",
        "root.Time.ObtainFromDHCP": "no",
        "root.Time.NTP.Server": "192.168.0.1",
        "root.Time.POSIXTimeZone": "UTC",
    }


