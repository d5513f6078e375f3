"""One wording of a tolerance window for every page and report (Window.describe): no
infinities, no bound that is not there, the unit once."""

from vts_hw.tolerance import DEFAULT_TOLERANCES, Window


def test_windows_read_as_a_person_says_them():
    assert Window.symmetric(1.0, 2.0, "px").describe() == "OK within ±1, ACTION beyond ±2 px"
    assert Window(tolerance_high=0, action_high=1, unit="markers").describe() == "OK ≤ 0, ACTION above 1 markers"
    assert Window(action_low=1).describe() == "ACTION below 1"
    assert Window(0.98, 0.99, 1.01, 1.02).describe() == "OK 0.99 … 1.01, ACTION outside 0.98 … 1.02"
    assert Window(tolerance_low=0.999, action_low=0.995).describe() == "OK ≥ 0.999, ACTION below 0.995"
    assert Window(tolerance_high=20, action_high=100, unit="ms").describe() == "OK ≤ 20, ACTION above 100 ms"


def test_no_default_window_reads_with_an_infinity_or_a_dash():
    for name, w in DEFAULT_TOLERANCES.items():
        text = w.describe()
        assert text and "∞" not in text and " - " not in text and "tol" not in text, (name, text)
