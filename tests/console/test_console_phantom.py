"""The phantom's spheres named on the Room page (issue 23 §1; docs/decisions/0073-phantom-names.md).

* The locator without a browser: the mapping procedure, run on the simulated phantom (its
  detections in two true cameras, a simulated SPECT volume), keeps the spheres' centres in the
  mapping file; the locator fits that shape to what the cameras see and names each sphere's
  detections S1..S7 as the mapping numbered them, wherever the phantom has moved since. The
  names are checked against the truth: each named detection lies on the projection of the true
  sphere the mapping's sphere is. Not confident (no phantom, three spheres, one camera, the wrong
  shape, an old mapping without the spheres, a locator that fails): nothing is named, and why.
* On the page, in Debian's Chromium against two simulated Axis cameras over HTTP: the spheres
  labelled S1..S7 in pink on both pictures, each where the true sphere of that name projects,
  the legend saying the phantom was fitted, its RMS and 7 of 7 spheres; the phantom taken off the
  table, no sphere is named any more.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from console_live import cam, served_room, until
from vts_hw.console.markers import Found
from vts_hw.console.names import MarkerNames
from vts_hw.console.phantom import PhantomNames, locator_for
from vts_hw.errors import DataError
from vts_hw.procedures.spect_mapping import SpectMapping
from vts_hw.sim_devices.scene import PHANTOM_PLACEMENT, Scene
from vts_hw.sim_devices.spect import SimSpect
from vts_hw.sim_devices.step_table import sphere_centres
from vts_hw.sim_devices.sync_truth import true_cameras, write_true_calibration, write_true_cameras
from vts_hw.vision.phantom_locator import PhantomLocator, phantom_template
from vts_hw.vision.registration import RigidTransform

pytestmark = pytest.mark.timeout(240)
PINK = "rgb(244, 114, 182)"  # console.css: .overlay circle.k-phantom


def seen(scene: Scene, t: float, seed: int = 0, drop=()):
    """Each camera's detections at ``t`` as the cameras would give them (true centres, 0.1 px
    noise, shuffled, wall markers and all), without the spheres named in ``drop``; and the truth
    ``{camera: {marker: (u, v)}}``."""
    rng = np.random.default_rng(seed)
    det, truth = {}, {}
    for n in scene.camera_names:
        tr = scene.truth(n, t)
        truth[n] = {m: (u, v) for m, u, v in tr}
        pts = np.array([(u, v) for m, u, v in tr if m not in drop]) + rng.normal(0, 0.1, (len(tr) - len(drop), 2))
        det[n] = pts[rng.permutation(len(pts))]
    return det, truth


def true_name(template: np.ndarray, scene: Scene, t: float) -> dict[str, str]:
    """The scene's name of each of the mapping's spheres (``S1``.. in the mapping's order): the true
    sphere nearest to it where the mapping was made (the SPECT frame is the scene's world)."""
    true = sphere_centres(scene, t)
    out = {}
    for k, p in enumerate(template):
        d = np.linalg.norm(true - p, axis=1)
        assert d.min() < 2.0, d  # the mapping measured the spheres where they were
        out[f"S{k + 1}"] = f"S{int(np.argmin(d)) + 1}"
    return out


def assert_named_as_the_truth(got, truth, to_true, n=7, px=1.0):
    """Every camera names ``n`` spheres, each at the true projection of the sphere it is."""
    assert not got.why, got.why
    for camera, pts in got.names.items():
        assert len(pts) == n and len({name for name, _, _ in pts}) == n, pts
        for name, x, y in pts:
            u, v = truth[camera][to_true[name]]
            assert np.hypot(x - u, y - v) < px, (camera, name, x, y, u, v)
    assert got.found == n and got.rms_mm < 1.0


@pytest.fixture(scope="module")
def mapped(tmp_path_factory):
    """The mapping procedure on the simulated phantom (turned a little on the table): the mapping
    file it saves, the true cameras' file (camera 1's frame, as a calibration gives it), the scene."""
    folder = tmp_path_factory.mktemp("phantom")
    scene = Scene.reference(seed=3, n_cameras=2)
    scene.add_phantom(rvec=(0.05, 0.4, -0.03))
    t = scene.start_epoch
    det, _ = seen(scene, t, seed=1)
    vol = SimSpect(seed=3).write(folder / "phantom.npz", sphere_centres(scene, t))
    m = SpectMapping.from_views(true_cameras(scene, t, frame="cam1"), det, vol).analyze()
    assert m.fre_mm < 1.0
    return m.save(folder / "spect_mapping.json"), write_true_cameras(scene, folder, t), scene


def test_the_mapping_keeps_the_spheres_and_the_locator_names_them_as_the_truth(mapped):
    mapping, cameras, scene = mapped
    template = phantom_template(mapping)
    assert template.shape == (7, 3)
    # kept in the order the mapping reports its spheres: sphere k's residual is template k's
    meta = RigidTransform.load(mapping).meta
    assert len(meta["residuals_mm"]) == 7 and meta["spheres_spect_mm"] == template.tolist()
    t = scene.start_epoch
    to_true = true_name(template, scene, t)
    loc = PhantomLocator.from_files(cameras, mapping, ["cam1", "cam2"])
    det, truth = seen(scene, t, seed=2)
    got = loc.locate(det)
    assert_named_as_the_truth(got, truth, to_true)
    assert got.source.startswith("phantom fitted, RMS 0.") and got.source.endswith("7 of 7 spheres")
    # 12 detections each: the 5 wall markers stay unnamed
    assert {n: len(d) for n, d in det.items()} == {"cam1": 12, "cam2": 12}

    # the shape, not the place: the phantom moved and turned on the table is named as well
    t2 = t + 10.0
    scene.set_phantom_pose((-0.2, 0.9, 0.1), tuple(np.add(PHANTOM_PLACEMENT, (30.0, 15.0, -40.0))), t2)
    det, truth = seen(scene, t2, seed=3)
    assert_named_as_the_truth(loc.locate(det), truth, to_true)

    # two spheres hidden: five named, the right five
    det, truth = seen(scene, t2, seed=4, drop=(to_true["S2"], to_true["S6"]))
    got = loc.locate(det)
    assert not got.why and got.found == 5 and got.source.endswith("5 of 7 spheres")
    for camera, pts in got.names.items():
        assert sorted(n for n, _, _ in pts) == ["S1", "S3", "S4", "S5", "S7"]
        for name, x, y in pts:
            assert np.hypot(x - truth[camera][to_true[name]][0], y - truth[camera][to_true[name]][1]) < 1.0


def test_not_confident_names_nothing_and_says_why(mapped, tmp_path):
    mapping, cameras, scene = mapped
    loc = PhantomLocator.from_files(cameras, mapping, ["cam1", "cam2"])
    t = scene.start_epoch
    to_true = true_name(phantom_template(mapping), scene, t)
    # three spheres only (a rigid fit of three has no residual to judge it by)
    det, _ = seen(scene, t, drop=[to_true[f"S{k}"] for k in (1, 2, 3, 4)])
    got = loc.locate(det)
    assert got.names == {} and ("3 of its 7 points" in got.why or "was not found among the 8 points" in got.why), got
    # one camera
    det, _ = seen(scene, t)
    got = loc.locate({"cam1": det["cam1"]})
    assert got.names == {} and got.why == "1 calibrated camera(s) see markers, two are needed"
    # another phantom's shape (this one 4 % larger): no fit within the limits
    big = PhantomLocator.from_files(cameras, mapping, ["cam1", "cam2"])
    big.template = big.template * 1.04
    got = big.locate(det)
    assert got.names == {} and got.why, got
    # too many markers to search within the tick
    crowd = PhantomLocator.from_files(cameras, mapping, ["cam1", "cam2"], max_detections=10)
    assert crowd.locate(det).why == "cam1, cam2 see(s) more than 10 markers: not searched"
    # a mapping made before the spheres were kept: none named, and what to do
    old = RigidTransform.load(mapping)
    old.meta.pop("spheres_spect_mm")
    old_path = old.save(tmp_path / "old_mapping.json")
    with pytest.raises(DataError, match="keeps no sphere centres .* run the mapping again"):
        phantom_template(old_path)

    class Rig:  # what locator_for reads of a RigConfig
        def __init__(self, cameras, mapping):
            self.calibration = type("C", (), {"cameras": cameras, "mapping": mapping})()
            self.cameras = [type("K", (), {"name": n})() for n in ("cam1", "cam2")]

    assert locator_for(Rig(cameras, old_path))[1].startswith(f"the mapping {old_path} keeps no sphere centres")
    assert locator_for(Rig(cameras, None)) == (
        None,
        "no VTS → SPECT mapping (calibration.mapping in rig.yaml): it keeps the phantom's shape",
    )
    assert locator_for(None)[1] == "the console was started without a rig config"


def found_of(det: dict, t: float) -> dict:
    return {
        n: Found(
            n,
            1,
            640,
            480,
            tuple({"n": i + 1, "x": float(x), "y": float(y), "d": 12.0} for i, (x, y) in enumerate(p)),
            t=t,
        )
        for n, p in det.items()
    }


def test_the_console_names_a_good_fit_and_clears_at_once_when_it_is_not(mapped):
    """PhantomNames between the worker's detections and the marker names: a good look names the
    spheres with the legend's words, a look at a phantom gone clears them at once (not after the
    hold), a locator that fails never raises into the worker."""
    mapping, cameras, scene = mapped
    names = MarkerNames()
    ph = PhantomNames(names, PhantomLocator.from_files(cameras, mapping, ["cam1", "cam2"]))
    assert ph.due() and ph.said() == "looking for the phantom"
    t = scene.start_epoch
    det, truth = seen(scene, t)
    assert ph.look(found_of(det, 1000.0)) and ph.why == ""
    assert re.fullmatch(r"phantom fitted, RMS \d+\.\d mm, 7 of 7 spheres", ph.said()), ph.said()
    marks, legend = names.label("cam1", list(found_of(det, 1000.0)["cam1"].markers))
    assert sorted(m["name"] for m in marks if m["kind"] == "phantom") == [f"S{k}" for k in range(1, 8)]
    assert sum(m["kind"] == "unidentified" for m in marks) == 5
    (entry,) = legend
    assert entry["kind"] == "phantom" and entry["found"] == 7 and entry["known"] == 7
    assert entry["source"].startswith("phantom fitted, RMS ") and entry["source"].endswith(" mm, 7 of 7 spheres")
    # a camera's detections a second older than the other's are not of the same instant
    stale = found_of(det, 1000.0)
    stale["cam2"] = Found("cam2", 1, 640, 480, stale["cam2"].markers, t=998.5)
    assert ph.look(stale) and names.current("cam1") == {} and "1 calibrated camera" in ph.why
    assert ph.said() == f"phantom not named: {ph.why}"
    # good again, then the phantom taken off the table: cleared at once
    assert ph.look(found_of(det, 1001.0)) and "phantom" in names.current("cam2")
    scene.set_phantom_pose((0.0, 0.0, 0.0), (4000.0, 0.0, 0.0), t + 5.0)
    det_gone, _ = seen(scene, t + 5.0)
    assert {n: len(d) for n, d in det_gone.items()} == {"cam1": 5, "cam2": 5}
    assert ph.look(found_of(det_gone, 1002.0)) and names.current("cam1") == {} and names.current("cam2") == {}
    assert ph.why

    class Broken:
        def locate(self, detections):
            raise RuntimeError("out of memory")

    ph2 = PhantomNames(names, Broken())
    names.set("cam1", "phantom", [("S1", 1.0, 2.0)], source="x")
    ph2._named = {"cam1"}
    assert ph2.look(found_of(det, 1003.0)) is True
    assert ph2.why == "the locator failed: RuntimeError: out of memory" and names.current("cam1") == {}
    assert PhantomNames(names, None, "no calibration").due() is False
    assert PhantomNames(names, None, "no calibration").said() == "phantom not looked for: no calibration"


def test_the_worker_does_not_look_for_the_phantom_while_a_recording_feeds_the_hub():
    """A scan started from the console records in the console's process: its live path is not
    made to share the process with the phantom's search (and a patient is on the table)."""
    import time

    from vts_hw.console.markers import MarkerWorker

    class Hub:
        names = ["cam1", "cam2"]
        fed = False

        def source(self, name):
            return "fed" if self.fed else "stream"

        def status(self, name):
            return {"viewers": 0}

    class Counting:
        looks = 0
        locator = object()

        def due(self):
            return True

        def said(self):
            return "looked"

        def look(self, found):
            self.looks += 1
            return False

    hub, phantom = Hub(), Counting()
    worker = MarkerWorker(hub, 50.0, MarkerNames(), phantom)
    try:
        assert until(lambda: phantom.looks >= 2, 10)
        hub.fed = True
        time.sleep(0.1)  # a look under way ends
        n = phantom.looks
        time.sleep(0.3)  # 15 rounds at 50 Hz
        assert phantom.looks == n
        assert worker.phantom_said() == "phantom not looked for while a recording feeds the cameras"
        hub.fed = False
        assert until(lambda: phantom.looks > n, 10)
        assert worker.phantom_said() == "looked"
    finally:
        worker.close()


# -- the Room page --------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def live(tmp_path_factory):
    from vts_hw.drivers.registry import open_camera
    from vts_hw.sim_devices.rig import SimRig
    from vts_hw.store import ResultsStore

    folder = tmp_path_factory.mktemp("phantom-room")
    db = folder / "results.sqlite"
    ResultsStore(db).close()
    with SimRig(n_cameras=2, seed=5) as rig, rig.env():
        rig.scene.add_phantom()  # before any camera serves a picture
        cal, mp = write_true_calibration(rig.scene, folder)
        mapped = rig.config(calibration={"stereo": str(cal), "spect": str(mp)})
        cams = {c.name: open_camera(c) for c in mapped.cameras}
        for c in cams.values():
            c.led_on()
        with served_room(rig, cams, db, rig_config=mapped) as lc:
            yield lc


def spheres_on(page, name):
    """The page's phantom circles of camera ``name``: [(label, x, y, stroke colour)]."""
    return cam(
        page,
        name,
        """e => [...e.querySelectorAll('svg circle[data-kind="phantom"]')].map(c =>
        [c.nextSibling.textContent, +c.dataset.x, +c.dataset.y, getComputedStyle(c).stroke])""",
    )  # its label follows it


def test_the_room_page_names_the_spheres_in_pink_where_they_are_and_none_once_removed(live, browser):
    page = browser.new_page(viewport={"width": 1366, "height": 768})
    try:
        page.goto(live.url)
        for name in ("cam1", "cam2"):
            got = until(lambda name=name: (lambda s: s if len(s) == 7 else None)(spheres_on(page, name)), 60, poll=0.3)
            assert got, (spheres_on(page, name), live.phantom.why)
            assert sorted(label for label, _, _, _ in got) == [f"S{k}" for k in range(1, 8)]
            assert {colour for _, _, _, colour in got} == {PINK}
            truth = {m: (u, v) for m, u, v in live.rig.scene.truth(name, live.rig.clock.now())}
            for label, x, y, _ in got:  # each where the true sphere of that name projects
                assert np.hypot(x - truth[label][0], y - truth[label][1]) < 1.5, (name, label, x, y, truth[label])
            legend = cam(page, name, "e => e.querySelector('.legend li[data-kind=\"phantom\"]').textContent")
            assert "phantom spheres: 7 of 7 named here, from phantom fitted, RMS " in legend, legend
            assert legend.endswith("mm, 7 of 7 spheres"), legend
            marks = cam(page, name, "e => e.querySelector('.marks').textContent")
            assert marks.startswith("12 found: 7 phantom spheres, 5 unidentified"), marks
        said = page.locator("#phantom")
        assert until(lambda: said.text_content().startswith("Phantom fitted, RMS "), 10, poll=0.3), said.text_content()
        assert said.is_visible()

        # the phantom taken off the table: no sphere named, on either picture, and no phantom in the legend
        live.rig.scene.set_phantom_pose((0.0, 0.0, 0.0), (4000.0, 0.0, 0.0), live.rig.clock.now())
        for name in ("cam1", "cam2"):
            assert until(
                lambda name=name: cam(
                    page,
                    name,
                    """e => e.querySelectorAll('svg circle').length === 5
                && !e.querySelector('svg circle[data-kind="phantom"]')
                && !e.querySelector('.legend li[data-kind="phantom"]')""",
                ),
                30,
                poll=0.3,
            ), (spheres_on(page, name), live.phantom.why)
        assert live.phantom.why
        assert until(lambda: said.text_content() == "Phantom not named: " + live.phantom.why, 10, poll=0.3), (
            said.text_content(),
            live.phantom.why,
        )
    finally:
        page.close()
