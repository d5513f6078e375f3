"""The frames hub: the latest frame of each camera, for any number of viewers, at no cost to the reader.

One :class:`CameraFeed` per camera of the rig. Its frames come from one *source* at a time:

* ``stream``: the hub's own reader, one reconnecting :class:`~vts_hw.camera_stream.FrameStream`
  (the one stream the suite has), opened only while someone watches the camera and closed
  after ``idle_close_s`` without a viewer;
* ``fed``: a recording in this process hands the hub the frames it already receives
  (:meth:`FramesHub.feed`, the recorder's ``on_frame``): the hub opens nothing, so a recording
  camera never gets a second viewer from the console ("too many viewers" is a real fault);
* ``off``: nothing (a camera the console must leave alone).

A frame is kept in a *slot*, never a queue: :meth:`FramesHub.feed` (and the reader) replace
the camera's latest frame under a lock and return; viewers read the slot when they are ready
(:meth:`FramesHub.latest`). A slow or gone viewer misses pictures and costs the reader
nothing. docs/decisions/0060-room-console.md says why, and how the Scan page attaches a
recording (:meth:`FramesHub.attach` before the recording opens its streams, ``feed`` as its
``on_frame``, :meth:`FramesHub.detach` after it).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field

from vts_hw.camera import Camera, Frame, Stream, StreamGap

SOURCES = ("stream", "fed", "off")
IDLE_CLOSE_S = 5.0  # a stream nobody watches is closed after this long
RETRY_AFTER_S = 3.0  # a reader that ended (a camera refused us for good) is tried again after this
QUIET_MIN_S = 2.0  # no frame for max(this, QUIET_FRAMES / fps): the camera is NOT ANSWERING
QUIET_FRAMES = 10
SETTLE_MIN_S = 0.2  # after closing its stream for a recording, before the recording opens its own


@dataclass(frozen=True)
class Latest:
    """The latest frame of a camera: ``seq`` counts the hub's frames of that camera (from 1),
    ``arrival`` is host epoch seconds when the hub got it."""

    seq: int
    frame: Frame
    arrival: float


@dataclass
class CameraFeed:
    name: str
    camera: Camera | None
    fps: float
    source: str = "stream"
    latest: Latest | None = None
    received: int = 0  # frames the hub got (reader or feed), since it started
    missing: int = 0  # frames the camera's stamps say were skipped (own stream only)
    viewers: int = 0
    unwatched_since: float = field(default_factory=time.monotonic)
    stream: Stream | None = None
    thread: threading.Thread | None = None
    opened_at: float | None = None  # monotonic s the current reader (or the feeding) started
    reader_ended: float | None = None  # monotonic s the last reader ended on its own (an error)
    error: str = ""  # why the camera is not answering (the reader's last error)
    fed_since: float | None = None

    @property
    def quiet_after(self) -> float:
        return max(QUIET_MIN_S, QUIET_FRAMES / max(self.fps, 0.1))


class FramesHub:
    """The cameras' latest frames. ``cameras``: name -> an open camera (``vts_hw.camera.Camera``)
    or None (a camera only ever fed). Thread-safe; ``close()`` stops every reader."""

    def __init__(
        self, cameras: dict, *, idle_close_s: float = IDLE_CLOSE_S, clock=time.time, stream_options: dict | None = None
    ):
        self.idle_close_s = float(idle_close_s)
        self.clock = clock
        self.stream_options = dict(stream_options or {})
        self._lock = threading.Lock()
        self._feeds = {
            name: CameraFeed(
                name, cam, float(getattr(cam, "fps", 25.0) or 25.0), source="stream" if cam is not None else "off"
            )
            for name, cam in cameras.items()
        }
        self._closed = threading.Event()
        self._janitor = threading.Thread(target=self._tend, name="console-hub", daemon=True)
        self._janitor.start()

    # -- what the page asks -------------------------------------------------------------------------
    @property
    def names(self) -> list[str]:
        return list(self._feeds)

    def latest(self, name: str) -> Latest | None:
        feed = self._feeds[name]
        with self._lock:
            return feed.latest

    def source(self, name: str) -> str:
        """Where the camera's frames come from now: ``stream``, ``fed`` or ``off`` (``status``'s
        ``source``, without the rest of it: the pages ask it per event tick)."""
        feed = self._feeds[name]
        with self._lock:
            return feed.source

    def counts(self, name: str) -> dict:
        """Frames received and skipped by the camera (own stream), and the reader's reconnects."""
        feed = self._feeds[name]
        with self._lock:
            st = feed.stream.stats if feed.stream is not None else None
            return {
                "received": feed.received,
                "missing": feed.missing,
                "reconnects": st.reconnects if st is not None else 0,
            }

    def status(self, name: str) -> dict:
        """What the camera is doing, as a word the page shows (``doing``): ``idle`` (nobody
        watches, no stream), ``streaming`` (the hub's own stream delivers), ``recording`` (a
        recording feeds the hub), ``not answering`` (watched or recording and no frame for
        longer than ``quiet_after``; ``why``: the reader's last error), ``off``. ``age``: seconds
        since the latest frame arrived (None: never)."""
        feed = self._feeds[name]
        now_m, now = time.monotonic(), self.clock()
        with self._lock:
            lt = feed.latest
            age = None if lt is None else max(0.0, now - lt.arrival)
            reading = feed.thread is not None and feed.thread.is_alive()
            since = feed.fed_since if feed.source == "fed" else feed.opened_at
            src = feed.source
            viewers = feed.viewers
            error = feed.error
        if src == "off":
            doing, started = "off", None
        elif src == "fed":
            doing, started = "recording", since
        elif viewers or reading:
            doing, started = "streaming", since
        else:
            doing, started = "idle", None
        if doing in ("streaming", "recording"):
            # no frame within quiet_after, and the source started longer ago than that
            fresh = age is not None and age <= feed.quiet_after
            if not fresh and (started is None or now_m - started > feed.quiet_after):
                doing = "not answering"
        return {
            "camera": name,
            "source": src,
            "doing": doing,
            "viewers": viewers,
            "seq": None if lt is None else lt.seq,
            "age": age,
            "why": error if doing == "not answering" else "",
            "received": feed.received,
            "fresh_within": feed.quiet_after,
        }

    # -- viewers ----------------------------------------------------------------------------------
    def watch(self, name: str) -> None:
        """A viewer of ``name`` arrived: its stream opens (now) if the hub owns it."""
        feed = self._feeds[name]
        with self._lock:
            feed.viewers += 1
        self._tend_one(feed)

    def unwatch(self, name: str) -> None:
        feed = self._feeds[name]
        with self._lock:
            feed.viewers = max(0, feed.viewers - 1)
            if feed.viewers == 0:
                feed.unwatched_since = time.monotonic()

    # -- sources ----------------------------------------------------------------------------------
    def feed(self, name: str, frame) -> None:
        """A frame of ``name`` from a recording in this process (its ``on_frame``). Returns at
        once; gaps (``StreamGap``) and cameras that are not ``fed`` are ignored."""
        f = self._feeds.get(name)
        if f is None or f.source != "fed" or not isinstance(frame, Frame):
            return
        self._put(f, frame)

    def attach(self, names, timeout: float = 10.0) -> None:
        """A recording of ``names`` is about to open its streams: the hub closes its own (and
        waits until they are closed, and a few frame intervals more for the camera to see its
        viewer go, so it never sees two) and takes what :meth:`feed` gives from now on."""
        threads = []
        for name in names:
            f = self._feeds[name]
            with self._lock:
                f.source, f.fed_since, f.error = "fed", time.monotonic(), ""
                f.latest = None  # a picture of before the recording is not the recording's
                stream, thread = f.stream, f.thread
            if stream is not None:
                stream.stop()
            if thread is not None:
                threads.append(thread)
        for t in threads:
            t.join(timeout)
        if threads:  # a camera notices a viewer gone when it next writes to it: a frame interval or so
            time.sleep(max(SETTLE_MIN_S, max(self._feeds[n].quiet_after / QUIET_FRAMES for n in names) * 3))

    def detach(self, names) -> None:
        """The recording of ``names`` ended: the hub opens its own stream again while watched."""
        for name in names:
            f = self._feeds[name]
            with self._lock:
                f.source = "stream" if f.camera is not None else "off"
                f.fed_since, f.reader_ended = None, None
            self._tend_one(f)

    def set_off(self, name: str) -> None:
        """Leave ``name`` alone: its stream is closed and not opened again until :meth:`detach`."""
        self.attach([name])
        with self._lock:
            self._feeds[name].source = "off"

    # -- the reader -------------------------------------------------------------------------------
    def _put(self, f: CameraFeed, frame: Frame) -> None:
        with self._lock:
            seq = (f.latest.seq if f.latest is not None else f.received) + 1
            f.latest = Latest(seq, frame, self.clock())
            f.received += 1
            f.error, f.reader_ended = "", None

    def _read(self, f: CameraFeed, stream: Stream) -> None:
        try:
            for item in stream:
                if isinstance(item, StreamGap):
                    with self._lock:
                        f.missing += item.missing
                        f.error = item.reason
                    continue
                self._put(f, item)
        except Exception as exc:  # a refused password, a reply that is not a stream: say so
            with self._lock:
                f.error = str(exc)
        finally:
            with self._lock:
                if f.stream is stream:
                    f.stream, f.reader_ended = None, time.monotonic()
                    f.thread = None

    def _start(self, f: CameraFeed, camera: Camera) -> None:
        opts = {"max_backoff": 1.0, **self.stream_options}
        stream = camera.stream(**opts)
        t = threading.Thread(target=self._read, args=(f, stream), name=f"console-{f.name}", daemon=True)
        f.stream, f.thread = stream, t
        if f.reader_ended is None:  # a retry after a reader that failed keeps its first start
            f.opened_at = time.monotonic()
        t.start()

    def _tend_one(self, f: CameraFeed) -> None:
        """Open the stream of a watched camera the hub owns; close one nobody watched for a while."""
        stop = None
        with self._lock:
            if self._closed.is_set():
                return
            now = time.monotonic()
            if f.source == "stream" and f.camera is not None:
                if f.viewers and f.thread is None:
                    if f.reader_ended is None or now - f.reader_ended >= RETRY_AFTER_S:
                        self._start(f, f.camera)
                elif not f.viewers and f.stream is not None and now - f.unwatched_since >= self.idle_close_s:
                    stop, f.stream, f.thread = f.stream, None, None
            if f.stream is not None:
                # a reader that is up but silent says why (FrameStream keeps its last error)
                err = f.stream.stats.last_error
                if err and (f.latest is None or self.clock() - f.latest.arrival > f.quiet_after):
                    f.error = err
        if stop is not None:
            stop.stop()

    def _tend(self) -> None:
        while not self._closed.wait(0.25):
            for f in self._feeds.values():
                self._tend_one(f)

    def close(self) -> None:
        self._closed.set()
        with self._lock:
            running = [(f.stream, f.thread) for f in self._feeds.values() if f.stream is not None]
            for f in self._feeds.values():
                f.stream = f.thread = None
        for stream, _ in running:
            stream.stop()
        for _, thread in running:
            if thread is not None:
                thread.join(5.0)
        self._janitor.join(2.0)


__all__ = ["FramesHub", "Latest", "SOURCES"]
