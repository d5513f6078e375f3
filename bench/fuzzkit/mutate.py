"""The fallback engine where atheris does not install: hypothesis, generating and mutating.

Each input is either random bytes or a seed (bench/fuzzkit/seeds.py) put through a few
mutations of the kinds libFuzzer uses: a byte changed, bits flipped, bytes inserted or
deleted, a range repeated, a piece of another seed spliced in, a dictionary token inserted,
an interesting number written over a field. Not coverage-guided, so it needs more inputs for
the same depth; the count is the same (``--runs``).
"""

from __future__ import annotations

import signal
from pathlib import Path

INTERESTING = (
    b"\x00",
    b"\xff",
    b"\x7f",
    b"\x80",
    b"\x00\x00",
    b"\xff\xff",
    b"\x7f\xff",
    b"\x00\x00\x00\x00",
    b"\xff\xff\xff\xff",
    b"\x7f\xff\xff\xff",
    b"0",
    b"-1",
    b"9" * 20,
    b"nan",
    b"inf",
)


def _mutate(data: bytes, draw, st, seeds: list[bytes], tokens) -> bytes:
    buf = bytearray(data)
    for _ in range(draw(st.integers(1, 6))):
        op = draw(st.integers(0, 7))
        pos = draw(st.integers(0, len(buf)))
        if op == 0 and buf and pos < len(buf):
            buf[pos] = draw(st.integers(0, 255))
        elif op == 1 and buf and pos < len(buf):
            buf[pos] ^= 1 << draw(st.integers(0, 7))
        elif op == 2:
            buf[pos:pos] = draw(st.binary(min_size=1, max_size=16))
        elif op == 3 and buf:
            del buf[pos : pos + draw(st.integers(1, 64))]
        elif op == 4 and buf:
            n = draw(st.integers(1, 64))
            buf[pos:pos] = buf[pos : pos + n] * draw(st.integers(1, 8))
        elif op == 5 and seeds:
            other = draw(st.sampled_from(seeds))
            a = draw(st.integers(0, len(other)))
            buf[pos:] = other[a : a + draw(st.integers(0, 4096))] + buf[pos:]
        elif op == 6 and tokens:
            buf[pos:pos] = draw(st.sampled_from(tokens))
        elif op == 7:
            v = draw(st.sampled_from(INTERESTING))
            buf[pos : pos + len(v)] = v
    return bytes(buf)


def run_hypothesis(recorder, seed_dir: Path, target, runs: int, seed: int, timeout: int) -> None:
    from hypothesis import HealthCheck, Phase, given, settings
    from hypothesis import seed as hseed
    from hypothesis import strategies as st

    seeds = [p.read_bytes()[: target.max_len] for p in sorted(seed_dir.iterdir())]
    tokens = list(target.tokens)

    @st.composite
    def inputs(draw):
        if not seeds or draw(st.integers(0, 9)) == 0:
            return draw(st.binary(max_size=min(target.max_len, 2048)))
        return _mutate(draw(st.sampled_from(seeds)), draw, st, seeds, tokens)[: target.max_len]

    def on_alarm(*_):
        raise TimeoutError(f"one input took more than {timeout} s")

    signal.signal(signal.SIGALRM, on_alarm)

    @hseed(seed)
    @settings(
        max_examples=max(1, runs - len(seeds)),
        deadline=None,
        database=None,
        derandomize=False,
        phases=[Phase.generate],
        suppress_health_check=list(HealthCheck),
    )
    @given(inputs())
    def run(data):
        signal.alarm(timeout)  # a hang is a crash (recorded), not the end of the run
        try:
            recorder(data)
        finally:
            signal.alarm(0)

    for s in seeds:  # the seeds themselves first, as libFuzzer does
        recorder(s)
    run()
