"""Every result on /al5d/result counted in a process of its own, at the default priority.

    python -m al5d_rig.result_counter      (in the server's ROS domain)

A flood brings a result for each of its moves (200,000 in the three-server rig);
counting them is a client's work, not an operator's stop button's. In the process
that sends the stops (which runs ahead of the load, as an operator's button does)
the counting ran at the stop path's own priority (three counters take about 100 CPU s
in a run of that rig); here it waits its turn like the flooding client.

Asked by lines of JSON on stdin, it answers each with a line of JSON on stdout:
`{"heard": PREFIX}` -> whether an outcome came for an id that begins with it;
`{"ids": [ids]}` -> true: the ids the next questions are about;
`{"count": null}` -> [of those ids, those with an outcome, those with more than one];
`{"missing": null}` -> those with none. It prints `{"ready": true}` first.
The ids go once, and each count looks at those still without an outcome: a flood's
200,000 ids, sent and counted whole at each half-second poll of the wait for its
results, cost about 0.2 s of CPU a poll (their JSON 50 ms, 30 of them in the asking
process at the stop path's priority; the count 130 ms).
`ResultCounter` is the rig's side.
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
from typing import Any


class ResultCounter:
    """The counting process, asked as `loadrig.Counter` is."""

    def __init__(self) -> None:
        from al5d_rig.loadrig import default_priority

        self.popen = subprocess.Popen(
            [sys.executable, "-m", "al5d_rig.result_counter"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            preexec_fn=default_priority,  # killed with this process too
        )
        self._lock = threading.Lock()
        self._ids: list[str] = []
        assert self._read().get("ready")

    def _read(self) -> Any:
        assert self.popen.stdout is not None
        line = self.popen.stdout.readline()
        if not line:
            raise RuntimeError("the result counter ended")
        return json.loads(line)

    def _ask(self, question: dict[str, Any]) -> Any:
        assert self.popen.stdin is not None
        with self._lock:
            self.popen.stdin.write(json.dumps(question) + "\n")
            self.popen.stdin.flush()
            return self._read()

    def heard(self, prefix: str) -> bool:
        return bool(self._ask({"heard": prefix}))

    def _about(self, ids: list[str]) -> None:
        if ids != self._ids:
            self._ask({"ids": ids})
            self._ids = list(ids)

    def count(self, ids: list[str]) -> tuple[int, int]:
        self._about(ids)
        got, twice = self._ask({"count": None})
        return int(got), int(twice)

    def missing(self, ids: list[str]) -> list[str]:
        self._about(ids)
        return list(self._ask({"missing": None}))

    def close(self) -> None:
        if self.popen.poll() is None:
            self.popen.kill()
        self.popen.wait(10)


def main() -> int:
    from al5d_rig.loadrig import Counter
    from al5d_rig.rospeer import Peer

    # The rig's own counter, read by a thread of its own as the server reads its inputs.
    counter = Counter(Peer(results=False, name="al5d_result_counter"))
    print(json.dumps({"ready": True}), flush=True)
    ids: list[str] = []
    among: set[str] = set()
    waiting: set[str] = set()  # of `ids`, those without an outcome when last looked
    for line in sys.stdin:
        question = json.loads(line)
        if "heard" in question:
            answer: Any = counter.heard(question["heard"])
        elif "ids" in question:
            ids, answer = question["ids"], True
            among, waiting = set(ids), set(ids)
        else:
            waiting = set(counter.missing(waiting))
            if "count" in question:
                answer = [len(among) - len(waiting), counter.repeated_among(among)]
            else:
                answer = [i for i in ids if i in waiting]
        print(json.dumps(answer), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
