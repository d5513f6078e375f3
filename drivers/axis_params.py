"""An Axis camera's parameters: listed by group and updated (VAPIX ``param.cgi``).

Current firmware (VAPIX 3) answers ``/axis-cgi/param.cgi`` for both; older firmware (VAPIX 2,
told apart by a 404 there) reads on ``view/param.cgi`` and writes on ``admin/param.cgi``.
:class:`AxisParameters` is the :class:`~vts_hw.camera.Parameters` role of an Axis camera
(over its :class:`~vts_hw.drivers.axis_client.AxisClient`); what ``vts camera setup`` sets
through it is :mod:`.axis_setup`.
"""

from __future__ import annotations

from collections.abc import Mapping

from vts_hw.drivers.axis_client import AxisClient
from vts_hw.drivers.axis_errors import BadReply, NotFound


class AxisParameters(AxisClient):
    """``get_params``/``set_params`` and the VAPIX version they are asked by, over the HTTP client."""

    _vapix: int | None = None

    @property
    def vapix_version(self) -> int:
        """3 when ``/axis-cgi/param.cgi`` exists, else 2 (``view/`` and ``admin/param.cgi``)."""
        if self._vapix is None:
            try:
                self._text("/axis-cgi/param.cgi", {"action": "list", "group": "Brand"})
                self._vapix = 3
            except NotFound:
                self._text("/axis-cgi/view/param.cgi", {"action": "list", "group": "Brand"})
                self._vapix = 2
        return self._vapix

    def get_params(self, group: str) -> dict[str, str]:
        """``root.``-less parameter names and values of a group, e.g. ``Image.I0``."""
        path = "/axis-cgi/param.cgi" if self.vapix_version == 3 else "/axis-cgi/view/param.cgi"
        text = self._text(path, {"action": "list", "group": group})
        out = {}
        for line in text.splitlines():
            if "=" in line:
                k, v = line.split("=", 1)
                out[k.strip().removeprefix("root.")] = v.strip()
        if not out:
            raise BadReply(self.name, f"camera {self.name} listed no parameters in group {group!r}")
        return out

    def set_params(self, values: Mapping[str, object]) -> None:
        path = "/axis-cgi/param.cgi" if self.vapix_version == 3 else "/axis-cgi/admin/param.cgi"
        params = {"action": "update"}
        params.update({k: str(v) for k, v in values.items()})
        text = self._text(path, params)
        if text.strip() != "OK":
            raise BadReply(self.name, f"camera {self.name} did not confirm the update: {text.strip()[:80]!r}")


__all__ = ["AxisParameters"]
