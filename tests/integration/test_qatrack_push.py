"""Pushing runs to QATrack+ through the outbox, against the simulated QATrack+ on 127.0.0.1
(vts_hw/sim_devices/qatrack_server.py) with its faults: down, slow, 500, 400, a duplicate,
an answer lost after the instance was made. Never twice, never lost, no secret anywhere."""

import json
import os

import pytest
import requests
import yaml

from fake_http import Answers
from inprocess_cli import run
from vts_hw.config import parse_rig
from vts_hw.errors import ConfigError
from vts_hw.qatrack import exit_code, push_runs, run_key, select_runs
from vts_hw.qatrack.client import drf_words
from vts_hw.sim_devices.qatrack_server import QATrackSim
from vts_hw.store import ResultsStore

TOKEN = "tok-5f1c9e0a7d3b4e2a9c8d"
PASSWORD = "pw-Zq8!secret-77"
DAILY = ["cam1_dx", "cam1_dy", "cam2_dx", "cam2_dy"]
MACROS = {
    "cam1/drift_x_px": "cam1_dx",
    "cam1/drift_y_px": "cam1_dy",
    "cam2/drift_x_px": "cam2_dx",
    "cam2/drift_y_px": "cam2_dy",
}


def qatrack_section(url, **over):
    q = {
        "url": url,
        "unit": "SPECT 1",
        "time_zone": "America/Toronto",
        "token_env": "QATRACK_TOKEN",
        "timeout_s": 2.0,
        "report": "none",
        "plots": False,
        "lists": {
            "daily": {"test_list": "VTS daily", "macros": dict(MACROS), "ignore": ["*/M*/*", "*/clock_offset_s"]}
        },
    }
    q.update(over)
    return q


def rig(url, **over):
    return parse_rig(
        {"rig": "room1", "cameras": [{"name": "cam1", "host": "127.0.0.1"}], "qatrack": qatrack_section(url, **over)},
        "test rig",
    )


@pytest.fixture()
def peer():
    with QATrackSim(
        {"VTS daily": DAILY},
        {"SPECT 1": ["VTS daily"], "SPECT 2": ["VTS daily"]},
        token=TOKEN,
        users={"physicist": PASSWORD},
    ) as sim:
        sim.slow_s = 1.5
        yield sim


@pytest.fixture()
def env(monkeypatch):
    monkeypatch.setenv("QATRACK_TOKEN", TOKEN)


def fill(store, n, rig_name="room1", t0=1.7e9, missing=None):
    ids = []
    for day in range(n):
        with store.begin_run("daily", rig=rig_name, started=t0 + day * 86400) as h:
            for cam in ("cam1", "cam2"):
                h.measure(cam, "drift_x_px", 0.1 * day, "px")
                h.measure(cam, "drift_y_px", None if (cam, day) == missing else -0.05 * day, "px")
                h.measure(cam, "clock_offset_s", 0.01, "s")
                h.measure(f"{cam}/M1", "drift_x_px", 0.1 * day, "px")
            ids.append(h.run_id)
    return ids


@pytest.fixture()
def store(tmp_path):
    with ResultsStore(tmp_path / "results.sqlite") as s:
        yield s


def states(store):
    return [i.state for i in store.outbox_items("qatrack")]


def test_each_run_posted_once_with_values_times_and_key(peer, env, store):
    cfg = rig(peer.url)
    ids = fill(store, 3, missing=("cam2", 1))
    out = push_runs(store, cfg.qatrack, select_runs(store, cfg.qatrack, "room1"))
    assert [o.how for o in out] == ["posted"] * 3 and exit_code(out) == 0
    assert peer.posts == 3 and states(store) == ["sent"] * 3
    tli = peer.instances[1]
    run = store.run(ids[1])
    assert tli["user_key"] == run_key(run) == f"vts-run-{run.uid}"
    assert tli["tests"]["cam1_dx"]["value"] == pytest.approx(0.1) and tli["tests"]["cam2_dy"]["skipped"]
    assert run_key(run) in tli["comment"] and "OK" in tli["comment"] and "room1" in tli["comment"]
    # 1.7e9 + 86400 s is 2023-11-15 22:13:20 UTC: 17:13:20 on the site's clock in Toronto, shown with its offset
    assert tli["work_started"] == "2023-11-15T17:13:20-05:00" and tli["work_completed"]
    assert store.outbox_items("qatrack", run_ids=[ids[1]])[0].remote == tli["url"]
    # a second push: nothing left to send; naming a sent run posts nothing either
    assert select_runs(store, cfg.qatrack, "room1") == []
    again = push_runs(store, cfg.qatrack, select_runs(store, cfg.qatrack, "room1", run_ids=ids))
    assert [o.how for o in again] == ["already sent"] * 3 and peer.posts == 3 and len(peer.instances) == 3


def test_a_run_already_in_qatrack_is_not_posted_again(peer, env, store):
    """The duplicate: an instance with the run's key is there (e.g. pushed from a copy of the
    store): the row becomes sent with that instance, nothing is posted."""
    cfg = rig(peer.url)
    (rid,) = fill(store, 1)
    there = peer.add_instance(run_key(store.run(rid)))
    out = push_runs(store, cfg.qatrack, [store.run(rid)])
    assert out[0].state == "sent" and out[0].how == "already there" and out[0].remote == there["url"]
    assert peer.posts == 0 and len(peer.instances) == 1


def test_down_then_back_sends_each_exactly_once(peer, env, store):
    cfg = rig(peer.url)
    fill(store, 4)
    peer.down()
    out = push_runs(store, cfg.qatrack, select_runs(store, cfg.qatrack, "room1"))
    assert exit_code(out) == 3 and states(store) == ["pending"] * 4
    assert "not reachable" in out[0].message and "connection refused" in out[0].message
    assert [o.how for o in out[1:]] == ["not tried"] * 3  # the batch stops: no waiting 4 times
    assert store.outbox_items("qatrack")[0].attempts == 1
    peer.up()
    retry = push_runs(store, cfg.qatrack, select_runs(store, cfg.qatrack, "room1", pending=True))
    assert exit_code(retry) == 0 and peer.posts == 4 and states(store) == ["sent"] * 4
    assert select_runs(store, cfg.qatrack, "room1", pending=True) == []


def test_slow_qatrack_times_out_and_stays_pending(peer, env, store):
    cfg = rig(peer.url, timeout_s=0.3)
    fill(store, 2)
    peer.fault = "slow"
    out = push_runs(store, cfg.qatrack, select_runs(store, cfg.qatrack, "room1"))
    assert states(store) == ["pending"] * 2 and "did not answer within 0.3 s" in out[0].message
    peer.fault = None
    push_runs(store, cfg.qatrack, select_runs(store, cfg.qatrack, "room1", pending=True))
    assert states(store) == ["sent"] * 2 and peer.posts == 2


def test_a_trickling_answer_ends_at_the_whole_request_deadline(peer, env, store):
    """A QATrack+ that answers its headers and then one byte at a time: the request ends at
    timeout_s as a whole (not per read), the run stays pending, and the batch stops."""
    import time

    cfg = rig(peer.url, timeout_s=1.0)
    fill(store, 2)
    peer.fault, peer.trickle_s = "trickle", 0.2
    t0 = time.monotonic()
    out = push_runs(store, cfg.qatrack, select_runs(store, cfg.qatrack, "room1"))
    assert time.monotonic() - t0 < 30  # bounded, whatever the machine's load (per read it never ends)
    assert [o.how for o in out] == ["failed", "not tried"] and "did not answer within 1 s" in out[0].message
    assert states(store) == ["pending"] * 2 and exit_code(out) == 3


def test_site_times_are_sent_as_its_wall_clock_and_read_back(env, store):
    """The push sends naive wall-clock times of qatrack.time_zone (QATrack+ takes no offset) and
    they land at the run's instant, in a zone south of the equator and across its clock change."""
    with QATrackSim({"VTS daily": DAILY}, {"SPECT 1": ["VTS daily"]}, token=TOKEN, time_zone="Australia/Sydney") as sim:
        cfg = rig(sim.url, time_zone="Australia/Sydney")
        # 2026-04-04 15:59:30 UTC is 02:59:30 AEDT on the 5th; at 16:00 UTC the clocks go back from 03:00 to 02:00
        ids = fill(store, 1, t0=1775318370.0 - 86400 * 3)  # three days before, in summer time (UTC+11)
        ids += fill(store, 1, t0=1775318370.0 + 7200)  # 03:59:30 AEST (UTC+10): after the repeated hour
        out = push_runs(store, cfg.qatrack, [store.run(i) for i in ids])
        assert [o.how for o in out] == ["posted", "posted"]
        assert sim.last_post["work_started"] == "2026-04-05 03:59:30"
        assert [i["work_started"] for i in sim.instances] == ["2026-04-02T02:59:30+11:00", "2026-04-05T03:59:30+10:00"]


def test_a_run_within_one_second_ends_at_the_next_second_not_a_minute_later(peer, env, store):
    """QATrack+ (TestListInstance.save) moves an end equal to the start 60 s on (the stand-in
    does as the real server: tests/interop/test_qatrack_real.py posts such times there); a run that
    starts and ends within one second is sent with its end at the next second and lands there."""
    t0 = 1790000000.0  # 2026-09-21 14:13:20 UTC: 10:13:20 in Toronto
    with store.begin_run("daily", rig="room1", started=t0 + 0.2) as h:
        h.measure("cam1", "drift_x_px", 0.1, "px")
        h.finish(finished=t0 + 0.7)
    out = push_runs(store, rig(peer.url).qatrack, [store.run(h.run_id)])
    assert [o.how for o in out] == ["posted"], out[0].line()
    assert (peer.last_post["work_started"], peer.last_post["work_completed"]) == (
        "2026-09-21 10:13:20",
        "2026-09-21 10:13:21",
    )
    shown = peer.instances[-1]
    assert (shown["work_started"], shown["work_completed"]) == (
        "2026-09-21T10:13:20-04:00",
        "2026-09-21T10:13:21-04:00",
    )
    # the site's own rule, as the real server has it: equal times sent, the end shown 60 s later
    r = requests.post(
        peer.url + "api/qa/testlistinstances/",
        headers={"Authorization": f"Token {TOKEN}"},
        json={
            **{k: v for k, v in peer.last_post.items() if k != "user_key"},
            "work_completed": peer.last_post["work_started"],
        },
        timeout=30,
    )
    assert r.status_code == 201, r.text
    assert r.json()["work_completed"] == "2026-09-21T10:14:20-04:00"


def test_a_run_in_the_repeated_hour_is_refused_in_one_sentence_before_posting(peer, env, store):
    cfg = rig(peer.url)
    (rid,) = fill(store, 1, t0=1793511000.0)  # 2026-11-01 05:30 UTC: 01:30 in Toronto, an hour that happens twice
    out = push_runs(store, cfg.qatrack, [store.run(rid)])
    assert out[0].state == "refused" and out[0].how == "repeated hour" and exit_code(out) == 4
    assert "2026-11-01 01:30:00 happens twice in America/Toronto" in out[0].message and "\n" not in out[0].message
    assert peer.posts == 0


def test_a_wrong_time_zone_stops_the_batch_before_posting(peer, env, store):
    """The site shows its times at another offset than qatrack.time_zone gives: nothing posted."""
    cfg = rig(peer.url, time_zone="Europe/Berlin")
    peer.add_instance("someone-else")  # an instance of the site, shown at Toronto's offset
    fill(store, 2)
    out = push_runs(store, cfg.qatrack, select_runs(store, cfg.qatrack, "room1"))
    assert [o.how for o in out] == ["wrong time zone", "not tried"] and exit_code(out) == 4
    assert "Europe/Berlin is not the site's TIME_ZONE" in out[0].message and peer.posts == 0
    assert states(store) == ["pending"] * 2


def test_an_instance_shown_at_a_wrong_time_is_said_and_stops_the_batch(env, store):
    """A fresh site (nothing there to tell its zone) in another zone than rig.yaml says: the first
    post's answer shows the times shifted; said, exit 4, the rest not posted."""
    with QATrackSim({"VTS daily": DAILY}, {"SPECT 1": ["VTS daily"]}, token=TOKEN, time_zone="Asia/Kolkata") as sim:
        cfg = rig(sim.url)
        fill(store, 2)
        out = push_runs(store, cfg.qatrack, select_runs(store, cfg.qatrack, "room1"))
        assert [o.how for o in out] == ["posted at a wrong time", "not tried"] and exit_code(out) == 4
        assert "is not the site's TIME_ZONE" in out[0].message and sim.posts == 1


def test_no_permission_and_a_wrong_base_url_are_one_clear_sentence(peer, env, store):
    peer.add_user("vts", token=TOKEN, perms=())  # the user lost its permission to add instances
    cfg = rig(peer.url)
    fill(store, 1)
    out = push_runs(store, cfg.qatrack, select_runs(store, cfg.qatrack, "room1"))
    assert out[0].how == "credentials refused" and "qa.add_testlistinstance" in out[0].message
    assert exit_code(out) == 4
    peer.add_user("vts", token=TOKEN, perms=("add",))
    wrong = rig(peer.url + "qatrack/")
    out = push_runs(store, wrong.qatrack, select_runs(store, wrong.qatrack, "room1"))
    assert out[0].state == "refused" and "is not the QATrack+ site's root" in out[0].message
    assert "login page" in out[0].message and peer.posts == 0


def test_an_answer_lost_after_the_instance_was_made_is_not_posted_twice(peer, env, store):
    cfg = rig(peer.url, timeout_s=0.5)
    (rid,) = fill(store, 1)
    peer.fault = "lose_answer"
    out = push_runs(store, cfg.qatrack, [store.run(rid)])
    assert out[0].state == "pending" and len(peer.instances) == 1  # made there, the answer lost
    peer.fault = None
    out = push_runs(store, cfg.qatrack, select_runs(store, cfg.qatrack, "room1", pending=True))
    assert out[0].how == "already there" and out[0].remote == peer.instances[0]["url"]
    assert len(peer.instances) == 1 and peer.posts == 1


def test_500_is_pending_and_the_batch_goes_on(peer, env, store):
    cfg = rig(peer.url)
    fill(store, 2)
    peer.fault = "500"
    out = push_runs(store, cfg.qatrack, select_runs(store, cfg.qatrack, "room1"))
    assert [o.how for o in out] == ["failed", "failed"] and exit_code(out) == 3
    assert "500" in out[0].message and "Server Error" in out[0].message
    peer.fault = None
    out = push_runs(store, cfg.qatrack, select_runs(store, cfg.qatrack, "room1", pending=True))
    assert exit_code(out) == 0 and peer.posts == 2


def test_a_refusal_is_one_sentence_in_qatracks_words_and_kept(peer, env, store):
    cfg = rig(peer.url)
    (rid,) = fill(store, 1)
    peer.fault = ("400", "Test list is not active for this unit")
    out = push_runs(store, cfg.qatrack, select_runs(store, cfg.qatrack, "room1"))
    assert out[0].state == "refused" and exit_code(out) == 4
    assert "(400): Test list is not active for this unit" in out[0].message and "\n" not in out[0].line()
    item = store.outbox_items("qatrack")[0]
    assert item.state == "refused" and "Test list is not active" in item.last_error
    peer.fault = None
    assert select_runs(store, cfg.qatrack, "room1", pending=True) == []  # --pending leaves it
    assert [r.id for r in select_runs(store, cfg.qatrack, "room1")] == [rid]  # a push without: retries it
    named = push_runs(store, cfg.qatrack, select_runs(store, cfg.qatrack, "room1", run_ids=[rid]))
    assert named[0].how == "posted" and peer.posts == 1 and states(store) == ["sent"]


def test_qatrack_missing_a_test_is_refused_with_its_message(peer, env, store):
    macros = dict(MACROS)
    del macros["cam2/drift_y_px"]
    cfg = rig(
        peer.url,
        lists={
            "daily": {
                "test_list": "VTS daily",
                "macros": macros,
                "ignore": ["*/M*/*", "*/clock_offset_s", "cam2/drift_y_px"],
            }
        },
    )
    fill(store, 1)
    out = push_runs(store, cfg.qatrack, select_runs(store, cfg.qatrack, "room1"))
    assert out[0].state == "refused" and "Missing data for tests: cam2_dy" in out[0].message


def test_a_macro_qatrack_does_not_have_is_noted_on_the_sent_run(peer, env, store):
    cfg = rig(
        peer.url,
        lists={
            "daily": {
                "test_list": "VTS daily",
                "macros": {**MACROS, "cam1/clock_offset_s": "cam1_clk"},
                "ignore": ["*/M*/*", "cam2/clock_offset_s"],
            }
        },
    )
    fill(store, 1)
    out = push_runs(store, cfg.qatrack, select_runs(store, cfg.qatrack, "room1"))
    assert out[0].how == "posted" and "kept no value for cam1_clk" in out[0].message
    assert (
        "cam1_clk" not in peer.instances[0]["tests"] and "kept no value" in store.outbox_items("qatrack")[0].last_error
    )


def test_an_unmapped_measurement_is_refused_before_anything_is_posted(peer, env, store):
    cfg = rig(peer.url, lists={"daily": {"test_list": "VTS daily", "macros": dict(MACROS), "ignore": ["*/M*/*"]}})
    fill(store, 1)
    out = push_runs(store, cfg.qatrack, select_runs(store, cfg.qatrack, "room1"))
    assert out[0].state == "refused" and out[0].how == "not mapped"
    assert "cam1/clock_offset_s, cam2/clock_offset_s" in out[0].message and "ignore" in out[0].message
    assert peer.requests == []  # not even asked


def test_no_assignment_for_the_unit_is_refused(peer, env, store):
    cfg = rig(peer.url, unit="SPECT 9")
    fill(store, 1)
    out = push_runs(store, cfg.qatrack, select_runs(store, cfg.qatrack, "room1"))
    assert (
        out[0].state == "refused"
        and "no active assignment of test list 'VTS daily' to unit 'SPECT 9'" in out[0].message
    )


def test_bad_token_stops_the_batch_and_no_secret_is_kept(peer, monkeypatch, store, tmp_path):
    monkeypatch.setenv("QATRACK_TOKEN", "wrong-" + TOKEN)
    cfg = rig(peer.url)
    fill(store, 3)
    out = push_runs(store, cfg.qatrack, select_runs(store, cfg.qatrack, "room1"))
    assert exit_code(out) == 4 and states(store) == ["pending"] * 3
    assert "Invalid token." in out[0].message and [o.how for o in out[1:]] == ["not tried"] * 2
    store.close()
    raw = b"".join(p.read_bytes() for p in tmp_path.glob("results.sqlite*"))
    assert TOKEN.encode() not in raw and all(TOKEN not in o.message for o in out)


def test_user_and_password_get_a_token(peer, monkeypatch, store):
    monkeypatch.setenv("QA_USER", "physicist")
    monkeypatch.setenv("QA_PW", PASSWORD)
    cfg = rig(peer.url, token_env=None, user_env="QA_USER", password_env="QA_PW")
    fill(store, 1)
    out = push_runs(store, cfg.qatrack, select_runs(store, cfg.qatrack, "room1"))
    assert out[0].how == "posted" and peer.requests[0][1] == "/api/get-token/"
    assert all(auth in ("", f"Token {TOKEN}") for _, _, auth in peer.requests)
    monkeypatch.setenv("QA_PW", "not-it")
    fill(store, 1, t0=1.8e9)
    out = push_runs(store, cfg.qatrack, select_runs(store, cfg.qatrack, "room1"))
    assert "Unable to log in with provided credentials." in out[0].message and "not-it" not in out[0].message


def test_runs_of_another_rig_are_not_pushed_with_this_rigs_unit(peer, env, store):
    cfg = rig(peer.url)
    fill(store, 1, rig_name="room2")
    assert select_runs(store, cfg.qatrack, "room1") == []
    with pytest.raises(Exception, match="room2"):
        select_runs(store, cfg.qatrack, "room1", run_ids=[1])


def test_attachments_are_the_drift_plots_and_the_report(peer, env, store):
    cfg = rig(peer.url, report="html", plots=True)
    fill(store, 3)
    out = push_runs(store, cfg.qatrack, [store.runs()[-1]])
    assert out[0].how == "posted", out[0].message
    names = peer.instances[0]["attachments"]
    assert names == ["vts-drift-run3-cam1.png", "vts-drift-run3-cam2.png", "vts-report-run3.html"]
    import base64

    files = {a["filename"]: base64.b64decode(a["value"]) for a in peer.last_post["attachments"]}
    assert files["vts-drift-run3-cam1.png"][:8] == b"\x89PNG\r\n\x1a\n"
    assert b"<html" in files["vts-report-run3.html"][:500].lower()


def test_config_is_strict_and_names_no_secret():
    with pytest.raises(ConfigError, match="qatrack.url .*must not hold a user or password"):
        rig("https://me:pw@qa.example.org/")
    with pytest.raises(ConfigError, match="token_env, or user_env and password_env"):
        rig("https://qa.example.org/", token_env=None)
    with pytest.raises(ConfigError, match="qatrack.lists.daily.macros .*not a QATrack\\+ macro"):
        rig("https://qa.example.org/", lists={"daily": {"test_list": "L", "macros": {"cam1/drift_x_px": "cam 1"}}})
    with pytest.raises(ConfigError, match="'steps' is not a procedure"):
        rig("https://qa.example.org/", lists={"steps": {"test_list": "L", "macros": {"x/steps_slope": "s"}}})
    assert rig("https://qa.example.org/qatrack").qatrack.api == "https://qa.example.org/qatrack/api/"


def test_drf_error_bodies_become_one_line():
    assert drf_words({"detail": "Invalid token."}) == "Invalid token."
    assert (
        drf_words({"non_field_errors": ["Missing data for tests: a, b\nWrong value"]})
        == "Missing data for tests: a, b Wrong value"
    )
    assert (
        drf_words({"unit_test_collection": ["Invalid hyperlink - Object does not exist."]})
        == "unit_test_collection: Invalid hyperlink - Object does not exist."
    )


@pytest.mark.timeout(600)  # a hang detector: several vts commands, slow on a loaded machine
def test_cli_daily_push_then_push_pending_and_dry_run(peer, sim_rig, tmp_path):
    """End to end: `vts qa daily --push` on the simulated rig with QATrack+ down (the QA's exit
    status stands, the run waits in the outbox), `vts qa push --pending` once it is back,
    `--dry-run`, and a second push adding nothing; the token is in no output."""
    data = sim_rig.config().model_dump(mode="json", exclude_none=True)
    data["results"] = {"url": f"sqlite:///{tmp_path / 'results.sqlite'}"}
    data["rig"] = "room1"
    data["qatrack"] = qatrack_section(
        peer.url, lists={"daily": {"test_list": "VTS daily", "macros": dict(MACROS), "ignore": ["*/M*/*", "cam?/*"]}}
    )  # mapped ones are sent; the rest of cam?/ not
    (tmp_path / "rig.yaml").write_text(yaml.safe_dump(data))
    env = dict(os.environ, VTS_CONFIG=str(tmp_path / "rig.yaml"), QATRACK_TOKEN=TOKEN, **sim_rig.env_vars())

    def vts(*a):
        p = run(*a, env=env)  # in this process (tests/inprocess_cli.py)
        assert TOKEN not in p.stdout + p.stderr and "Traceback" not in p.stderr
        return p

    assert vts("qa", "drift", "--set-baseline", "--frames", "2").returncode == 0
    peer.down()
    p = vts("qa", "daily", "--frames", "2", "--push")
    assert p.returncode == 0, p.stdout + p.stderr
    assert "left pending" in p.stderr and "connection refused" in p.stderr and "--pending" in p.stderr
    peer.up()
    p = vts("qa", "push", "--dry-run")
    assert p.returncode == 0 and "cam1_dx" in p.stdout and "nothing posted" in p.stdout and peer.requests == []
    p = vts("qa", "push", "--pending", "--json")
    out = json.loads(p.stdout)
    assert p.returncode == 0 and [o["how"] for o in out["outcomes"]] == ["posted"] and peer.posts == 1
    p = vts("qa", "push")
    assert p.returncode == 0 and "nothing to push" in p.stdout and peer.posts == 1
    p = vts("qa", "push", "99")
    assert p.returncode == 2 and "no run 99" in p.stderr
    env.pop("QATRACK_TOKEN")
    p = vts("qa", "push", "1")
    assert p.returncode == 2 and "QATRACK_TOKEN is not set" in p.stderr


def test_cli_usage_errors_are_one_sentence(tmp_path, monkeypatch, capsys):
    from vts_hw.cli import main

    def vts(*a):
        with pytest.raises(SystemExit) as e:
            main(list(a))
        err = capsys.readouterr().err
        assert "Traceback" not in err and len([ln for ln in err.splitlines() if "vts:" in ln or "Error:" in ln]) == 1, (
            err
        )
        return e.value.code, err

    plain = tmp_path / "plain.yaml"
    plain.write_text(
        yaml.safe_dump(
            {
                "rig": "room1",
                "cameras": [{"name": "cam1", "host": "127.0.0.1"}],
                "results": {"url": f"sqlite:///{tmp_path / 'r.sqlite'}"},
            }
        )
    )
    code, err = vts("qa", "push", "--config", str(plain))
    assert code == 2 and "no qatrack: section" in err and str(plain) in err
    full = tmp_path / "rig.yaml"
    full.write_text(
        yaml.safe_dump({**yaml.safe_load(plain.read_text()), "qatrack": qatrack_section("http://127.0.0.1:9/")})
    )
    monkeypatch.setenv("QATRACK_TOKEN", TOKEN)
    code, err = vts("qa", "push", "--config", str(full), "--pending", "3")
    assert code == 2 and "not both" in err


@pytest.mark.parametrize(
    "body, words",
    [
        (b'{"results": [{"name": "VTS daily"}]}', "without its url"),
        (b'{"results": {"url": "x"}}', "not a list of objects"),
        (b'{"results": [5]}', "not a list of objects"),
        (b'{"results": [{"url": "u"}], "next": 7}', "next page that is not a link"),
    ],
)
def test_an_assignment_list_of_the_wrong_shape_is_one_sentence(body, words):
    # found by bench/fuzz.py (qatrack): KeyError, TypeError from urljoin went through
    from vts_hw.qatrack.client import QATrackClient, Unreachable

    client = QATrackClient("http://127.0.0.1:9/", ("token", "t"), session=Answers(body))
    with pytest.raises(Unreachable, match=words):
        client.assignment("SPECT 1", "VTS daily")


def test_instances_and_errors_of_the_wrong_shape_are_one_sentence():
    # found by bench/fuzz.py (qatrack): results[0] of a dict was a KeyError; a deep body a RecursionError
    from vts_hw.qatrack.client import QATrackClient, Refused, Unreachable

    client = QATrackClient("http://127.0.0.1:9/", ("token", "t"), session=Answers(b'{"results": {"a": 1}}'))
    with pytest.raises(Unreachable, match="not a list of objects"):
        client.instance_with_key("k")
    client = QATrackClient("http://127.0.0.1:9/", ("token", "t"), session=Answers((400, b"[" * 5000 + b"]" * 5000)))
    with pytest.raises(Refused, match=r"refused POST .*\(400\)"):
        client.create_instance({})
    deep = "deep"
    for _ in range(30):
        deep = [deep]
    assert drf_words(deep) == "(no message)" and drf_words({"detail": ["shallow"]}) == "shallow"
