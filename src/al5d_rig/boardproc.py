"""`al5d emulator` in a process of its own, its records streamed back: a board that does not
share the GIL of the process that measures it (the tests' floods, the benchmarks)."""

from __future__ import annotations

import os
import signal
import subprocess
import threading
from collections.abc import Callable
from pathlib import Path

from al5d.arm.config import ArmConfig
from al5d.clock import Deadline
from al5d.ssc32u.emulator import Record
from al5d.ssc32u.emulator.board import RESET, Board
from al5d_rig.proc import AL5D, dies_with_parent, said


class BoardProcess:
    """An emulated SSC-32U at `link`; `records` and `wait_for` as the in-process emulator has."""

    def __init__(self, link: Path, baud: int = 9600, config: ArmConfig | None = None) -> None:
        self.port = str(link)
        self.baud = baud
        self._records: list[Record] = []
        self._replayed = 0
        #: The board's model here, fed the records it streams (see `model`).
        self._model = Board(config, baud=baud) if config is not None else None
        self._changed = threading.Condition()
        # The board's USB link (al5d emulator's default), or AL5D_BOARD_TRANSPORT=uart: a plain
        # serial line, to see which figures the USB link's model moves (docs/performance.md).
        transport = os.environ.get("AL5D_BOARD_TRANSPORT", "usb")
        args = ["--baud", str(baud), "--link", str(link), "--record", "-", "--transport", transport]
        self.popen = subprocess.Popen(
            [AL5D, "emulator", *args],
            stdout=subprocess.PIPE,
            text=True,
            env=os.environ.copy(),
            preexec_fn=dies_with_parent,
        )
        assert self.popen.stdout is not None
        first = said(self.popen.stdout)  # the device path comes first
        assert first == str(link), f"al5d emulator said {first!r}"
        threading.Thread(target=self._read, name="board-records", daemon=True).start()

    def _read(self) -> None:
        assert self.popen.stdout is not None
        for line in self.popen.stdout:
            rec = Record.from_json(line)
            with self._changed:
                self._records.append(rec)
                self._changed.notify_all()

    @property
    def records(self) -> list[Record]:
        with self._changed:
            return list(self._records)

    def wait_for(
        self, predicate: Callable[[list[Record]], bool], timeout: float = 5.0
    ) -> list[Record]:
        deadline = Deadline(timeout)
        with self._changed:
            while True:
                records = list(self._records)
                if predicate(records):
                    return records
                if deadline.expired:
                    raise TimeoutError(f"board process: condition not met in {timeout} s")
                self._changed.wait(deadline.left())

    def model(self) -> Board:
        """The board's logic replayed here from its record: the same servo model (reach
        times, trajectories) as the process's own, without sharing its GIL.

        The replay starts from the same power-up state, and every line the board acted on
        takes effect at the same time, and so does every reset; lines it never ran
        (cancelled by ESC, or noise) are left out.
        """
        assert self._model is not None, "BoardProcess(config=...) to replay the servos"
        with self._changed:
            new = self._records[self._replayed :]
            self._replayed = len(self._records)
        for rec in new:
            if rec.source == RESET:
                self._model.reset(rec.t_effect)
            elif rec.ignored == "cancelled by ESC" or (rec.ignored or "").startswith("noise"):
                continue
            else:
                self._model.execute(rec.raw, rec.t_effect)
        return self._model

    def close(self) -> None:
        if self.popen.poll() is None:
            self.popen.send_signal(signal.SIGTERM)
            try:
                self.popen.wait(10)
            except subprocess.TimeoutExpired:
                self.popen.kill()
                self.popen.wait(5)
