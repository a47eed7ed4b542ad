"""Termination signals during a run or a sweep: what they set or raise, and what they leave alone."""

import os
import signal
import threading

import pytest

from wamctl.experiments.runner import signals_as_event, signals_as_interrupt


@pytest.fixture
def sigint_handled():
    """SIGINT as an interactive Python has it (a suite started in the background inherits it ignored, and an
    ignored signal is left alone by design)."""
    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, old)


def test_signals_as_event_sets_the_event_and_restores_the_handlers(sigint_handled):
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    with signals_as_event() as stop:
        assert not stop.is_set()
        os.kill(os.getpid(), signal.SIGINT)        # would raise KeyboardInterrupt under the default handler
        assert stop.wait(2.0)
    assert {s: signal.getsignal(s) for s in before} == before


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGHUP], ids=["ctrl-c", "hangup"])
def test_an_ignored_signal_stays_ignored(sig):
    """A background job keeps ignoring Ctrl-C, a run started with nohup SIGHUP: neither context installs its
    handler over SIG_IGN."""
    old = signal.signal(sig, signal.SIG_IGN)
    try:
        with signals_as_event() as stop:
            assert signal.getsignal(sig) is signal.SIG_IGN
            os.kill(os.getpid(), sig)
            assert not stop.wait(0.2)
        with signals_as_interrupt():
            assert signal.getsignal(sig) is signal.SIG_IGN
    finally:
        signal.signal(sig, old)


def test_signals_as_interrupt_raises_keyboard_interrupt_naming_the_signal():
    with pytest.raises(KeyboardInterrupt, match="SIGTERM"):
        with signals_as_interrupt():
            os.kill(os.getpid(), signal.SIGTERM)
            threading.Event().wait(2.0)


def test_outside_the_main_thread_nothing_is_installed(sigint_handled):
    seen = {}

    def body():
        with signals_as_event() as stop:
            seen["handler"] = signal.getsignal(signal.SIGINT)
            seen["set"] = stop.is_set()
    t = threading.Thread(target=body)
    t.start()
    t.join()
    assert seen == {"handler": signal.getsignal(signal.SIGINT), "set": False}


def test_ctrl_c_while_the_report_is_written_says_the_run_is_complete_and_how_to_write_it(tmp_path, monkeypatch):
    """The run's data are complete; only the report was cut short: the user is told so (exit 130), and the
    manifest keeps ``completed``."""
    import json

    from conftest import rotation_spec

    from wamctl.experiments import runner
    from wamctl.specs import parse_spec

    def interrupted_report(path):
        raise KeyboardInterrupt
    monkeypatch.setattr(runner, "write_report", interrupted_report)
    spec = parse_spec(rotation_spec(rotation={"joints": [7], "mode": "one_at_a_time", "hold_s": 0.1}), "t")
    with pytest.raises(runner.RunInterrupted, match=r"the run completed; its report was interrupted, "
                                                    r"`wamctl report .*` writes it") as caught:
        runner.run_spec(spec, None, tmp_path)
    assert caught.value.exit_code == 130
    (run_dir,) = [p for p in tmp_path.iterdir() if p.is_dir()]
    assert json.loads((run_dir / "manifest.json").read_text())["status"] == "completed"
