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
    from al5d_interfaces.msg import InstructionResult
    from rclpy.node import Node

    from al5d.ros.dds import start_context
    from al5d.ros.executors import Spinner
    from al5d_rig.loadrig import QOS_ALL

    seen: dict[str, int] = {}
    lock = threading.Lock()

    def on_result(msg: InstructionResult) -> None:
        with lock:
            seen[msg.id] = seen.get(msg.id, 0) + 1

    context = start_context()
    node = Node("al5d_result_counter", context=context)
    node.create_subscription(InstructionResult, "/al5d/result", on_result, QOS_ALL)
    spinner = Spinner(node, context)
    print(json.dumps({"ready": True}), flush=True)
    for line in sys.stdin:
        question = json.loads(line)
        with lock:
            if "heard" in question:
                answer: Any = any(i.startswith(question["heard"]) for i in seen)
            elif "count" in question:
                ids = question["count"]
                answer = [sum(i in seen for i in ids), sum(seen.get(i, 0) > 1 for i in ids)]
            else:
                answer = [i for i in question["missing"] if i not in seen]
        print(json.dumps(answer), flush=True)
    spinner.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
