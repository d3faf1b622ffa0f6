"""Progress and set-up logging (springsim.progress) and the CLI's -v/--quiet."""

import logging

import pytest
from helpers import PENDULUM_YAML

from springsim import cli, make_integrator, simulate, simulate_adaptive
from springsim import progress as progress_module
from springsim.model.builder import ModelBuilder
from springsim.progress import ProgressLog, as_progress, format_seconds, logging_configured, phase

SCENE = PENDULUM_YAML


def _pendulum():
    b = ModelBuilder()
    b.add_particle([0, 0, 1], mass=1.0, fixed=True)
    b.add_particle([0, 0, 0], mass=1.0)
    b.add_spring(0, 1, 100.0)
    return b.finalize()


def test_format_seconds():
    assert format_seconds(3.25) == "3.2 s" and format_seconds(42.4) == "42 s"
    assert format_seconds(185) == "3 min 05 s" and format_seconds(7380) == "2 h 03 min"


def test_progress_log_lines_steps_and_time(caplog):
    """Lines name the step (or the simulated time) and the fraction; a time-left estimate follows the first call."""
    p = ProgressLog(interval=0.0)
    with caplog.at_level(logging.INFO, logger="springsim"):
        p(1, 10)
        p(5, 10)
        p(0.5, 2.0)
    msgs = [r.getMessage() for r in caplog.records]
    assert msgs[0].startswith("step 1/10 (10%)") and "elapsed" in msgs[0]
    assert msgs[1].startswith("step 5/10 (50%)") and "left" in msgs[1]
    assert msgs[2].startswith("t = 0.5 s of 2 s (25%)")


def test_progress_log_is_silent_before_its_interval(caplog):
    p = ProgressLog(interval=1e9)
    with caplog.at_level(logging.DEBUG, logger="springsim"):
        for k in range(1, 11):
            p(k, 10)
    assert p.lines == 0 and not caplog.records


def test_phase_levels(caplog):
    """A phase logs its start and time at DEBUG, at INFO when it was slow."""
    with caplog.at_level(logging.DEBUG, logger="springsim"):
        with phase("quick"):
            pass
        with phase("slow", slow=0.0):
            pass
    levels = {r.getMessage().split(":")[0].split(" ...")[0]: r.levelno for r in caplog.records if ":" in r.getMessage()}
    assert levels == {"quick": logging.DEBUG, "slow": logging.INFO}


def test_as_progress():
    def f(k, n):
        return None

    assert as_progress(None) is None and as_progress(f) is f and isinstance(as_progress(True), ProgressLog)
    with pytest.raises(TypeError, match="progress must be"):
        as_progress("yes")


def test_simulate_progress_true_logs_through_logging(caplog, monkeypatch):
    """progress=True in simulate and simulate_adaptive logs ProgressLog lines to the springsim logger."""
    monkeypatch.setattr(progress_module, "PROGRESS_INTERVAL_S", 0.0)
    m = _pendulum()
    with caplog.at_level(logging.INFO, logger="springsim"):
        simulate(m, make_integrator("symplectic_euler", m), 0.01, 3, progress=True)
        simulate_adaptive(m, "tr_bdf2", 0.05, progress=True)
    msgs = [r.getMessage() for r in caplog.records]
    assert any(s.startswith("step 3/3 (100%)") for s in msgs)
    assert any(s.startswith("t = 0.05 s of 0.05 s (100%)") for s in msgs)


@pytest.fixture
def set_level():
    """``set_level(logger, level)`` through ``setLevel`` (which clears logging's caches), undone after the test."""
    saved = []

    def set_level(log, level):
        saved.append((log, log.level))
        log.setLevel(level)

    yield set_level
    for log, level in reversed(saved):
        log.setLevel(level)


def _unconfigure_logging(monkeypatch, set_level):
    """Logging as a script that never configures it has it: no handlers on the root logger (pytest's removed)."""
    monkeypatch.setattr(logging.getLogger(), "handlers", [])
    set_level(logging.getLogger(), logging.WARNING)
    set_level(logging.getLogger("springsim"), logging.NOTSET)
    monkeypatch.setattr(progress_module, "PROGRESS_INTERVAL_S", 0.0)


def _run_with_progress():
    m = _pendulum()
    simulate(m, make_integrator("symplectic_euler", m), 0.01, 3, progress=True)
    simulate_adaptive(m, "tr_bdf2", 0.05, progress=True)


def test_progress_true_prints_to_stderr_without_logging_configuration(capsys, monkeypatch, set_level):
    """progress=True shows its lines on stderr by itself when the application has not configured logging."""
    _unconfigure_logging(monkeypatch, set_level)
    assert not logging_configured()
    _run_with_progress()
    out, err = capsys.readouterr()
    assert out == ""
    assert "springsim: step 3/3 (100%)" in err and "springsim: t = 0.05 s of 0.05 s (100%)" in err


def test_progress_true_uses_the_springsim_loggers_configuration(capsys, monkeypatch, set_level):
    """A handler on the springsim logger receives the lines, and nothing else is printed to stderr."""
    _unconfigure_logging(monkeypatch, set_level)
    records = []
    handler = logging.Handler(logging.INFO)
    handler.emit = records.append
    log = logging.getLogger("springsim")
    monkeypatch.setattr(log, "handlers", log.handlers + [handler])
    set_level(log, logging.INFO)
    _run_with_progress()
    assert capsys.readouterr() == ("", "")
    assert any(r.getMessage().startswith("step 3/3 (100%)") for r in records)


def test_progress_true_uses_the_root_loggers_configuration(capsys, monkeypatch, set_level):
    """With only the root logger configured (at WARNING, as by ``logging.basicConfig()``), progress is not printed."""
    _unconfigure_logging(monkeypatch, set_level)
    records = []
    handler = logging.Handler(logging.NOTSET)
    handler.emit = records.append
    monkeypatch.setattr(logging.getLogger(), "handlers", [handler])
    _run_with_progress()
    assert capsys.readouterr() == ("", "") and records == []
    set_level(logging.getLogger(), logging.INFO)  # the application asks for INFO: it gets it
    _run_with_progress()
    assert capsys.readouterr() == ("", "")
    assert any(r.getMessage().startswith("step 3/3 (100%)") for r in records)


def test_cli_verbose_logs_setup_phases(capsys, tmp_path):
    """-v logs the set-up phases on stderr; the default keeps a fast run's stderr empty; --quiet prints nothing."""
    f = tmp_path / "s.yaml"
    f.write_text(SCENE)
    assert cli.main(["run", str(f), "-v"]) == 0
    out, err = capsys.readouterr()
    assert "springsim: loading" in err and "sparsity pattern of 3 DOFs" in err and "running 5 step(s)" in err
    assert "scene:" in out
    assert cli.main(["run", str(f)]) == 0
    assert capsys.readouterr().err == ""
    assert cli.main(["run", str(f), "--quiet"]) == 0
    assert capsys.readouterr() == ("", "")
    assert cli.main(["run", str(f), "-v", "--quiet"]) == 2  # mutually exclusive
    assert "not allowed with" in capsys.readouterr().err


def test_cli_restores_the_library_logger(tmp_path):
    """After a CLI run the springsim logger has its NullHandler only, its level and propagation as before."""
    f = tmp_path / "s.yaml"
    f.write_text(SCENE)
    log = logging.getLogger("springsim")
    before = (list(log.handlers), log.level, log.propagate)
    assert cli.main(["run", str(f), "-v", "--steps", "1"]) == 0
    assert (list(log.handlers), log.level, log.propagate) == before
