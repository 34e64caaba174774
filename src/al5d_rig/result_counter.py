"""Every result on /al5d/result counted in a process of its own, at the default priority.

    python -m al5d_rig.result_counter      (in the server's ROS domain)

A flood brings a result for each of its moves (200,000 in the three-server rig);
counting them is a client's work, not an operator's stop button's. In the process
that sends the stops (which runs ahead of the load, as an operator's button does)
the counting ran at the stop path's own priority (three counters take about 100 CPU s
in a run of that rig); here it waits its turn like the flooding client.

Asked by lines of JSON on stdin, it answers each with a line of JSON on stdout:
`{"heard": PREFIX}` -> whether an outcome came for an id that begins with it;
`{"count": [ids]}` -> [ids with an outcome, ids with more than one];
`{"missing": [ids]}` -> the ids with none. It prints `{"ready": true}` first.
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

    def count(self, ids: list[str]) -> tuple[int, int]:
        got, twice = self._ask({"count": ids})
        return int(got), int(twice)

    def missing(self, ids: list[str]) -> list[str]:
        return list(self._ask({"missing": ids}))

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
    for line in sys.stdin:
        question = json.loads(line)
        if "heard" in question:
            answer: Any = counter.heard(question["heard"])
        elif "count" in question:
            answer = counter.count(question["count"])
        else:
            answer = counter.missing(question["missing"])
        print(json.dumps(answer), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
