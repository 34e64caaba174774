"""What a tab's input shares with its page (`page.Page` is one): the page's lock, what it
knows of the arm, its widgets and its judgement, named here so that the tabs' modules
(`sliders.py`, `target.py`) need not import the page that holds them."""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    from al5d.arm.instruction import Instruction
    from al5d.web.jog import Jog
    from al5d.web.panel import Panel
    from al5d.web.plan import Planner
    from al5d.web.scene import ArmScene


class PageParts(Protocol):
    """The page, as its tabs' input uses it: every attribute under `lock`."""

    degrees: dict[str, float] | None
    state: str
    lost: bool
    page_move_to: str | None
    jog: Jog
    panel: Panel
    planner: Planner
    scene: ArmScene

    @property
    def lock(self) -> threading.RLock: ...

    def precheck(self, instr: Instruction | str) -> str:
        """The reason the server would refuse `instr` from where the arm is, or ''."""
        ...

    def send_instruction(self, instr: Instruction) -> bool:
        """Send `instr` to the server; False when there is none to send it to."""
        ...
