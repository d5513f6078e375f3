"""The simulated QATrack+ answers as the real one does.

tests/qatrack_conversation.py sends the same requests to a site and reduces each answer to what
must agree. The real QATrack+ 3.1's answers were recorded once into
tests/data/qatrack_real_answers.json (the command is in that file and in the module); here the
stand-in (vts_hw/sim_devices/qatrack_server.py), set up as the real site's setup_site.py sets
up its own, gets the same conversation and must answer every request the same way: that is how
we know the fast tests of the push would have caught what the real server refuses.
tests/interop/test_qatrack_real.py pushes into the real server itself.
"""

import json

import pytest

import qatrack_conversation as conv
from vts_hw.sim_devices.qatrack_server import QATrackSim

RECORDED = json.loads(conv.FIXTURE.read_text())


@pytest.fixture(scope="module")
def stand_in_answers():
    with QATrackSim(
        {conv.DAILY_LIST: conv.DAILY, "VTS step test": ["x_slope", "y_slope", "z_slope", "diff_max"]},
        {conv.UNIT: [conv.DAILY_LIST, "VTS step test"]},
        token="t-vts",
        users={"vts": "pw-vts"},
        time_zone=RECORDED["time_zone"],
    ) as sim:
        sim.add_user("noperm", token="t-noperm", perms=())
        yield {
            a["step"]: a["answer"] for a in conv.converse(conv.Context(sim.url, "t-vts", "t-noperm", "vts", "pw-vts"))
        }


def test_the_recording_covers_every_step_of_the_conversation():
    assert [a["step"] for a in RECORDED["answers"]] == [name for name, _ in conv.STEPS]


@pytest.mark.parametrize("step", [name for name, _ in conv.STEPS])
def test_the_stand_in_answers_as_the_real_qatrack_does(stand_in_answers, step):
    real = next(a["answer"] for a in RECORDED["answers"] if a["step"] == step)
    assert stand_in_answers[step] == real
