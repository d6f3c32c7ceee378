import os
import signal

import pytest

from babblegen.interrupts import Interrupted, Interrupts


def _term() -> None:
    os.kill(os.getpid(), signal.SIGTERM)


def test_a_signal_outside_a_write_stops_at_once():
    done = []
    with Interrupts(), pytest.raises(Interrupted, match="SIGTERM"):
        _term()
        done.append("after")
    assert done == []


def test_a_signal_during_a_write_waits_for_the_write_to_finish():
    steps = []
    with Interrupts() as stop, pytest.raises(Interrupted, match="SIGINT"), stop.protected():
        os.kill(os.getpid(), signal.SIGINT)
        steps.append("rest of the write")
        with stop.protected():  # nested sections hold it to the outermost end
            steps.append("inner")
        steps.append("end of the write")
    assert steps == ["rest of the write", "inner", "end of the write"]


def test_a_second_signal_during_a_write_stops_at_once():
    steps = []
    with Interrupts() as stop, pytest.raises(Interrupted), stop.protected():
        _term()
        steps.append("first held")
        _term()
        steps.append("never")
    assert steps == ["first held"]


def test_signals_during_closing_are_recorded_only():
    with Interrupts() as stop:
        with stop.closing():
            _term()
            _term()
        assert stop.pending == "SIGTERM"


def test_previous_handlers_come_back():
    before = signal.getsignal(signal.SIGTERM)
    with Interrupts():
        assert signal.getsignal(signal.SIGTERM) is not before
    assert signal.getsignal(signal.SIGTERM) is before


@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")
def test_a_stop_dropped_by_a_destructor_is_raised_at_the_next_protected_section():
    """Python ignores an exception raised while a ``__del__`` runs (the simulator frees its old scene on every
    reset); a signal landing there must still stop the run."""

    class Freed:
        def __del__(self):
            os.kill(os.getpid(), signal.SIGTERM)  # the handler's Interrupted is dropped ("Exception ignored")

    with Interrupts() as stop:
        Freed()
        with pytest.raises(Interrupted, match="SIGTERM"), stop.protected():
            pass
