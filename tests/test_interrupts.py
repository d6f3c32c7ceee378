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


def test_library_code_neither_swallows_nor_converts_a_stop():
    """SAPIEN's URDF parser, run in every scene rebuild, re-raises what it catches as a ValueError: a stop raised
    there ended the run with exit status 1."""

    def parse_required_attribute():
        try:
            _term()
            return 1.0
        except Exception:
            raise ValueError("Missing required attribute size when parsing an object of type Box") from None

    with Interrupts(), pytest.raises(Interrupted, match="SIGTERM"):
        parse_required_attribute()


def test_a_signal_while_an_exception_is_handled_is_recorded_only():
    """A raise there would replace the exception being handled and cut its clean-up short."""
    cleaned = []
    with Interrupts() as stop, pytest.raises(Interrupted, match="SIGINT"):
        try:
            os.kill(os.getpid(), signal.SIGINT)  # the stop
        finally:
            _term()  # a second signal during the clean-up
            cleaned.append("the rest of the clean-up")
    assert cleaned == ["the rest of the clean-up"] and stop.pending == "SIGINT"


def test_a_stop_recorded_outside_raising_is_raised_on_entering_it():
    with Interrupts(raising=False) as stop:
        _term()  # as during the console script's imports: recorded
        assert stop.pending == "SIGTERM"
        with pytest.raises(Interrupted, match="SIGTERM"), stop.raising():
            pytest.fail("not reached")
        _term()  # after it: recorded only
        with stop.protected():
            pass


def test_an_error_raised_while_a_stop_was_handled_counts_as_the_stop():
    from babblegen.interrupts import stopped_by

    def wrapped():
        try:
            raise Interrupted("SIGTERM")
        except BaseException:  # a library's bare ``except:``
            raise RuntimeError("the library's own error") from None

    with pytest.raises(RuntimeError) as caught:
        wrapped()
    assert stopped_by(caught.value)
    assert not stopped_by(RuntimeError("unrelated"))


def test_a_run_from_python_gets_handlers_for_its_duration_and_the_console_scripts_are_kept():
    from babblegen.interrupts import for_command, installed

    before = signal.getsignal(signal.SIGTERM)
    with for_command() as stop:
        assert installed() is stop and signal.getsignal(signal.SIGTERM) is not before
    assert installed() is None and signal.getsignal(signal.SIGTERM) is before
    console = Interrupts(raising=False).install()
    try:
        with for_command() as stop:
            assert stop is console
        assert installed() is console, "stays until the process ends"
    finally:
        console.restore()


def test_a_child_started_while_spawning_never_acts_on_the_signals_and_a_stop_meanwhile_waits():
    import subprocess
    import sys
    import time

    from babblegen.interrupts import spawning

    with Interrupts() as stop:
        with pytest.raises(Interrupted, match="SIGTERM"), spawning():
            child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
            _term()  # blocked here until the child is started
            started = "no stop raised inside"
        assert started and stop.pending == "SIGTERM"
    try:
        for s in (signal.SIGINT, signal.SIGTERM):  # as Ctrl-C in a terminal, or `timeout`, send to the group
            child.send_signal(s)
        time.sleep(0.5)
        assert child.poll() is None, "the child left the stopping to its parent"
    finally:
        child.kill()
        child.wait()
