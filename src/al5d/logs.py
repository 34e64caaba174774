"""The processes' log: lines to stderr in one format, written by a thread of their own.

`al5d serve`, its ROS side's processes and the command line's tools log so.
"""

from __future__ import annotations

import atexit
import logging
import logging.handlers
import queue
import sys

LOG_FORMAT = "%(asctime)s.%(msecs)03d %(levelname)s %(message)s"


def setup_logging(level: str) -> None:
    """Log lines to stderr, written by a thread of their own: a thousand refusals logged in a
    flood cost their callers a hand-over each, not a write to the terminal each."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter(LOG_FORMAT, datefmt="%H:%M:%S"))
    lines: queue.SimpleQueue[logging.LogRecord] = queue.SimpleQueue()
    listener = logging.handlers.QueueListener(lines, handler)
    listener.start()
    atexit.register(listener.stop)  # the last lines are written before the process ends
    hand_over = logging.handlers.QueueHandler(lines)
    hand_over.setFormatter(logging.Formatter("%(message)s"))  # the listener's handler formats
    logging.basicConfig(level=level.upper(), handlers=[hand_over])
