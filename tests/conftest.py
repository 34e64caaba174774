"""Shared fixtures: the shipped arm configuration and an emulated SSC-32U on a real pty."""

from __future__ import annotations

import faulthandler
import gc
import json
import logging
import os
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from al5d_rig import domains

# A ROS domain of our own for the whole run (`domains.claim`): every server and client
# the tests start inherits it.
os.environ["ROS_DOMAIN_ID"] = str(domains.claim())
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"

from al5d.arm.config import ArmConfig, load_config
from al5d.arm.states import State
from al5d.owner.loop import Owner
from al5d.ssc32u.driver import SSC32U
from al5d.ssc32u.emulator import Emulator
from al5d_rig.armrig import ON_FAILURE, Rig, make_rig
from al5d_rig.proc import said_so_far


@pytest.fixture(scope="session")
def config() -> ArmConfig:
    return load_config()


@pytest.fixture
def emulator(config: ArmConfig) -> Iterator[Emulator]:
    with Emulator(config, baud=9600) as emu:
        yield emu


@pytest.fixture
def board(emulator: Emulator) -> Iterator[SSC32U]:
    with SSC32U(emulator.port, 9600) as b:
        emulator.wait_for(lambda rs: any(r.raw == b"VER" for r in rs))
        emulator.clear_records()
        yield b


@pytest.fixture
def rig(config: ArmConfig, caplog: pytest.LogCaptureFixture) -> Iterator[Rig]:
    """A driver, started and ready, on an emulated board in this process."""
    caplog.set_level(logging.DEBUG, logger="al5d")
    yield from make_rig(config)


@pytest.fixture
def linked(config: ArmConfig, tmp_path: object) -> Iterator[tuple[Emulator, Owner]]:
    """A driver on an emulator behind a link, so that the board can be unplugged and back."""
    link = f"{tmp_path}/ssc32u"
    with Emulator(config, link=link) as emu:
        driver = Owner.on_port(config, link)
        driver.start()
        try:
            driver.wait_for_state(State.READY, 10)
            yield emu, driver
        finally:
            driver.close()


#: Where each pytest-xdist worker's fault handler writes (a worker that dies of a fault, a
#: segfault or an abort, or that pytest-timeout ends, is reported by xdist as "crashed",
#: with nothing of why): printed at the end of the run. A worker killed outright (SIGKILL)
#: writes nothing.
FAULTS = Path(__file__).resolve().parents[1] / "build" / "reliability" / "faults"
FAULT_RECORD = pytest.StashKey[Any]()


def pytest_configure(config: pytest.Config) -> None:
    """Before any worker starts: Fast DDS's files of processes of earlier runs that were
    killed are removed (`al5d_rig.shm`), and so are the fault records of an earlier run."""
    if not hasattr(config, "workerinput"):
        from al5d_rig import shm

        shm.clean()
        for old in FAULTS.glob("*.txt"):
            old.unlink()


@pytest.hookimpl(trylast=True)
def pytest_sessionstart(session: pytest.Session) -> None:
    """In a worker: its fault handler writes to a file of its own (after pytest's own
    plugin has pointed it at the worker's stderr, which xdist does not show)."""
    worker = getattr(session.config, "workerinput", None)
    if worker is not None:
        FAULTS.mkdir(parents=True, exist_ok=True)
        record = (FAULTS / f"{worker['workerid']}-{os.getpid()}.txt").open("w")
        session.config.stash[FAULT_RECORD] = record  # open for as long as the worker runs
        faulthandler.enable(file=record, all_threads=True)


#: A test still running this long after its timeout has a hang that holds the interpreter.
HELD_PAST_TIMEOUT_S = 30.0


@pytest.hookimpl(tryfirst=True, optionalhook=True)
def pytest_timeout_set_timer(item: pytest.Item, settings: Any) -> bool | None:
    """In a worker: a test that overran its timeout is named in the worker's fault record,
    with every thread's stack, before pytest-timeout ends the worker (it prints both to the
    worker's terminal, which xdist does not show: the run said only "crashed")."""
    import pytest_timeout

    record = item.config.stash.get(FAULT_RECORD, None)
    if record is None or settings.method != "thread":
        return None  # pytest-timeout's own

    def overran() -> None:
        record.write(f"Timeout: {item.nodeid} ran past its {settings.timeout:g} s\n")
        record.flush()
        faulthandler.dump_traceback(file=record, all_threads=True)
        pytest_timeout.timeout_timer(item, settings)  # its report, then os._exit(1)

    timer = threading.Timer(settings.timeout, overran)
    timer.name = f"timeout {item.nodeid}"
    # The timer's thread needs the interpreter, which a hang in native code may hold for
    # ever (seen: Fast DDS spinning in a participant's destruction, the run held until
    # `make test`'s own limit); faulthandler's watchdog needs nothing, and ends the worker.
    faulthandler.dump_traceback_later(
        settings.timeout + HELD_PAST_TIMEOUT_S, exit=True, file=record
    )

    def cancel() -> None:
        faulthandler.cancel_dump_traceback_later()
        timer.cancel()
        timer.join()

    item.cancel_timeout = cancel  # type: ignore[attr-defined]  # pytest-timeout's cancel hook calls it
    timer.start()
    return True


def pytest_sessionfinish(session: pytest.Session) -> None:
    """Under pytest-xdist, a worker hands its fuzz counts to the controller."""
    from al5d_rig.fuzzcount import CASES

    output = getattr(session.config, "workeroutput", None)
    if output is not None:
        output["fuzz_cases"] = dict(CASES)


@pytest.hookimpl(optionalhook=True)
def pytest_testnodedown(node: Any, error: Any) -> None:
    """A worker's fuzz counts; for one that died, what it wrote as it died, at once on the
    controller's stderr: a run whose controller then waited on for its replacement (an
    idle CI run, 98 % in) was stopped with the summary, and the record, never written."""
    from al5d_rig.fuzzcount import CASES

    CASES.update(getattr(node, "workeroutput", {}).get("fuzz_cases", {}))
    if error is None:
        return
    worker = node.gateway.id
    for record in sorted(FAULTS.glob(f"{worker}-*.txt")):
        text = record.read_text(errors="replace").strip() or "(nothing: killed outright?)"
        lines = [f"--- worker {record.stem} went down ({error}); it wrote:", *fault_summary(text)]
        print("\n".join(lines), file=sys.stderr, flush=True)


def fault_summary(text: str, frames: int = 8) -> list[str]:
    """A fault handler's record with each thread's innermost `frames` frames (the rest is
    pytest's and xdist's)."""
    kept: list[str] = []
    depth = 0
    for line in text.splitlines():
        framed = line.startswith("  File ")
        depth = depth + 1 if framed else 0
        if depth <= frames:
            kept.append(line)
    return kept


def pytest_terminal_summary(terminalreporter: Any) -> None:
    """What a worker that died wrote as it died, and the fuzz suites' case counts, at the
    end of the run (the counts in build/reliability too)."""
    from al5d_rig.fuzzcount import CASES

    for record in sorted(FAULTS.glob("*.txt")):
        text = record.read_text(errors="replace").strip()
        if text:
            terminalreporter.write_sep("-", f"fault in worker {record.stem}")
            for line in fault_summary(text):
                terminalreporter.write_line(line)
    if not CASES:
        return
    terminalreporter.write_sep("-", "fuzz cases run")
    for suite, n in sorted(CASES.items()):
        terminalreporter.write_line(f"{suite}: {n}")
    out = Path(__file__).resolve().parents[1] / "build" / "reliability"
    out.mkdir(parents=True, exist_ok=True)
    (out / "fuzz.json").write_text(json.dumps(dict(CASES), indent=1))


#: The files that keep one worker longest (seconds of one worker in a `make test` here
#: with four workers: 233, 109, 80, 78, 70, 60, 57, 49, 44, 42, 42, 40).
#: pytest-xdist hands out whole files in collection order (the Makefile turns off its
#: own order, by the number of tests in a file): these go first, so that none starts
#: near the end and keeps the run going alone (test_web.py, collected last, did).
LONGEST_FIRST = (
    "test_web.py",
    # The physical twin's: a demo of 30 s and two boards of 20 s, each waiting on real time.
    "test_twin_demo.py",
    "test_twin_process.py",
    "test_docs.py",
    "test_ros_e2e.py",
    "test_ros_client.py",
    "test_app_cli_errors.py",
    "test_app_record.py",
    "test_arm_model.py",
    "test_fuzz_ros.py",
    "test_web_calibrate.py",
    "test_app_teach.py",
    "test_web_teach.py",
    "test_arm_reliability.py",
)


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Any:
    """A failed call's report carries what its fixtures would have its reader know
    (`ON_FAILURE`), taken then, while the rig's processes are as the failure found them."""
    report = yield
    facts = item.stash.get(ON_FAILURE, None)
    if report.when == "call" and report.failed and facts is not None:
        try:
            report.sections.append(("at the failure", facts()))
        except Exception as error:  # the report must not be lost for its extra facts
            report.sections.append(("at the failure", f"not found: {error!r}"))
    if report.when == "call" and report.failed:
        try:
            said = said_so_far(item.stash[STARTED])
        except Exception as error:
            said = f"not found: {error!r}"
        if said:
            report.sections.append(("what the test's processes said", said))
    return report


#: When a test's setup began (monotonic): the processes it started are those started since.
STARTED = pytest.StashKey[float]()


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item: pytest.Item) -> None:
    item.stash[STARTED] = time.monotonic()


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The longest files first; a file's own tests keep their order (a stable sort)."""
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))


@pytest.hookimpl(trylast=True)
def pytest_collection_finish(session: pytest.Session) -> None:
    """What every test module and its imports made (about 227,000 objects, all of them for
    the whole run), collected once and frozen out of the garbage collector's sight
    (`gc.freeze`). A full collection went over all of them: 134 ms on an idle machine, and
    up to 1.9 s in a worker of an idle `make test` (four workers on two cores), with the
    interpreter held all that time. The boards emulated in this process and its ROS peers
    answered nothing meanwhile: a server took such a board for lost ("no answer to QP3,
    asked twice") while its test waited for a stop's outcome."""
    gc.collect()
    gc.freeze()
