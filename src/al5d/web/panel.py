"""The page's widgets: STOP in a window of its own, and the side panel (the state, the
lost-server banner, the controls, what happened). No lock and no ROS: the page calls it
under its own lock and wires its handlers.

STOP lives outside the side panel, in a small window over the 3D view, so that
nothing the side panel does (scrolling, another tab, being collapsed by its
chevron) can take it out of view. Its window has no grip bar, tab strip or
minimize button (a style rule hides them), so it cannot be minimized or dragged
into a dock either.
"""

from __future__ import annotations

import html
import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt
import viser
from viser import uplot

from al5d.arm.config import ArmConfig
from al5d.model import JOINTS
from al5d.model.transforms import Vec3
from al5d.web.plan import OutcomeLog


class TimeNotTaken(ValueError):
    """A time box holds a value outside its own range: send nothing, say why."""


def _box_ms(number: Any) -> int | None:
    """A time box's whole ms, None for 0. The browser keeps a box to its range; an update
    crafted past it (a negative time, 5e9 ms) is refused here, before it becomes an
    instruction that no message can carry."""
    value, top = number.value, number.max
    if not isinstance(value, int | float) or not (math.isfinite(value) and 0 <= value <= top):
        raise TimeNotTaken(f"time {value!r} ms is outside the box's 0..{top} ms")
    return int(value) or None


#: What the page shows for the state while the server is out of contact: its last state
#: is not known to hold (a stop, a fault or its end may have come meanwhile).
NO_CONTACT = "no_contact"
STATE_COLOURS = {
    "ready": "#2b8a3e",
    "moving": "#1971c2",
    "stopped": "#c92a2a",
    "fault": "#e67700",
    "initializing": "#868e96",
    "shutting_down": "#868e96",
    "ended": "#495057",
    NO_CONTACT: "#868e96",
}
#: The states a release is for: the release button is shown in these only.
RELEASABLE = ("stopped", "fault")


def held(state: str) -> str:
    """Why a move asked on the page in `state` (one of RELEASABLE) is not sent."""
    return f"not sent: the arm is {state}; release it first"


#: The Target tab's optional fields: key, (label, hint).
TOOL_FIELDS = {
    "pitch": ("pitch (deg)", "the gripper's axis to the horizontal, + up; empty: the nearest"),
    "roll": ("roll (deg)", "the wrist rotate; empty: as it is"),
    "gripper": ("gripper (deg)", "the gripper servo; empty: as it is"),
}
JOINT_COLOURS = ("#e03131", "#1971c2", "#2f9e44", "#f08c00", "#9c36b5", "#0c8599")
#: Where the STOP window floats: this far from the 3D view's bottom-left corner (px).
STOP_MARGIN_PX = 16
STOP_WIDTH_PX = 260
#: Below this width viser's client draws no windows but a bottom sheet, where STOP's
#: window is a collapsed section (Mantine's `xs` breakpoint, 36em).
PHONE_MAX_WIDTH_PX = 575

# Hooks: the window that holds #al5d-stop-style is STOP's (CSS :has), Mantine's Styles API
# class names, and viser's dock attributes for the window's chrome. If viser renames the
# latter, the STOP window shows its chrome again: still out of the side panel, only
# minimizable. The icon's svg is placed absolutely after the whitespace of its HTML, a
# space's width to the right: at STOP's size that is over the "S" unless it is put at 0.
# viser draws no number box beside a slider as disabled: the rule greys it
# and takes the pointer from it (the page undoes a value typed there all the same).
PAGE_STYLE = """<style id="al5d-stop-style">
[data-floating-window]:has(#al5d-stop-style) :is([data-dock-griphandle],[data-dock-strip],
[data-dock-minimize]) { display: none !important; }
[data-floating-window]:has(#al5d-stop-style) {
  z-index: 300 !important; box-shadow: 0 0 0 3px #fff, 0 2px 14px rgba(0,0,0,.35) !important; }
[data-floating-window]:has(#al5d-stop-style) .mantine-Button-root {
  height: 4rem !important; font-size: 1.8rem !important; }
[data-floating-window]:has(#al5d-stop-style) .mantine-Button-label {
  letter-spacing: .1em; font-weight: 800 !important; }
[data-floating-window]:has(#al5d-stop-style) .mantine-Button-section {
  margin-inline-end: .45em !important; }
[data-floating-window]:has(#al5d-stop-style) .mantine-Button-section svg { left: 0; }
.mantine-Flex-root:has(> .mantine-Slider-root [data-disabled]) > .mantine-NumberInput-root {
  opacity: .45; pointer-events: none; }
</style>"""


#: viser 1.1.1 labels an input with `<label for=UUID>`, but gives a text box (`add_text`) no
#: such id, a slider's id to a <div> (which a label cannot name) and the number box beside a
#: slider no label at all: none of those has an accessible name. This names each, from its
#: row's label, whenever the panel's rows come and go (a tab opened, a row redrawn). It runs
#: as an image's `onload`: viser's HTML elements run no <script>.
NAME_INPUTS_JS = """if (!window.al5dNames) { window.al5dNames = true;
  const name = () => {
    for (const label of document.querySelectorAll("label[for]")) {
      const target = document.getElementById(label.htmlFor);
      if (target && target.labels && target.labels.length) continue;
      const row = label.closest(".mantine-Flex-root");
      if (!row) continue;
      const text = label.textContent.trim();
      const controls = row.querySelectorAll("input:not([type=hidden]), textarea, [role=slider]");
      controls.forEach((control, i) => {
        const said = i === 0 ? text : `${text} (number)`;
        if (control.getAttribute("aria-label") !== said) control.setAttribute("aria-label", said);
      });
    }
  };
  let due = false;
  new MutationObserver(() => {
    if (!due) { due = true; queueMicrotask(() => { due = false; name(); }); }
  }).observe(document.body, { childList: true, subtree: true });
  name();
}"""
#: A transparent pixel, to carry the script.
PIXEL = "data:image/gif;base64,R0lGODlhAQABAIAAAAAAAP///yH5BAEAAAAALAAAAAABAAEAAAIBRAA7"


def names_html() -> str:
    """The element that names the panel's inputs (`NAME_INPUTS_JS`)."""
    script = html.escape(NAME_INPUTS_JS, quote=True)
    return f'<img id="al5d-names" alt="" hidden src="{PIXEL}" onload="{script}">'


def phone_style(stop_id: str) -> str:
    """On a phone, STOP (its element's id) pinned over the top of the screen, big, above
    everything: one tap, whatever the bottom sheet shows. There its window is a section
    of the sheet, expanded by the panel (a collapsed one makes its content inert): the
    section's header, whose tap would collapse it, is not drawn. No ancestor makes a
    containing block, so `position: fixed` takes STOP out to the screen."""
    stop = f'[id="{stop_id}"]'
    return (
        f'<style id="al5d-phone-style">@media (max-width: {PHONE_MAX_WIDTH_PX}px) {{'
        f" .mantine-Tabs-root:has({stop}) > :first-child {{ display: none !important; }}"
        f" {stop} {{ position: fixed !important; top: 8px; left: 8px; right: 8px;"
        " width: auto !important; height: 4rem !important; font-size: 1.8rem !important;"
        " z-index: 1000 !important; box-shadow: 0 0 0 3px #fff, 0 2px 14px rgba(0,0,0,.35); }"
        f" {stop} .mantine-Button-label {{ letter-spacing: .1em; font-weight: 800 !important; }}"
        f" {stop} .mantine-Button-section {{ margin-inline-end: .45em !important; }}"
        f" {stop} .mantine-Button-section svg {{ left: 0; }}"
        # viser's toasts (software WebGL, a lost connection) come down from the top: below
        # STOP, not over it.
        " .mantine-Notifications-root { top: calc(4rem + 20px) !important; }"
        "}</style>"
    )


#: The web view's pulse: the page's element changes this often while its server is heard.
PULSE_S = 0.25
#: No pulse for this long: the browser has lost its web view (a link cut, a hung process).
#: Four pulses missed: at most PULSE_S + PAGE_LOST_S + 0.1 s (the check's period) from a
#: cut to the page saying so, within the 2 s promised.
PAGE_LOST_S = 1.0
#: The page's own watchdog. A browser learns nothing of a cut link from its websocket (TCP
#: waits minutes before it gives up), so the page watches the pulse: once it stops, a layer
#: over everything but STOP says so and takes the clicks (a click on a stalled socket would
#: reach the arm whenever the link came back). STOP's window stays above it: a STOP sent
#: late still stops the arm, and nothing else can be.
PAGE_WATCH_JS = f"""if (!window.al5dWatch) {{ window.al5dWatch = true;
  let seen = null, at = performance.now();
  setInterval(() => {{
    const pulse = document.getElementById("al5d-pulse");
    const beat = pulse ? pulse.dataset.n : null;
    const now = performance.now();
    if (beat !== seen) {{ seen = beat; at = now; }}
    const age = (now - at) / 1000;
    let layer = document.getElementById("al5d-page-lost");
    if (age <= {PAGE_LOST_S}) {{ if (layer) layer.remove(); return; }}
    if (!layer) {{
      layer = document.createElement("div");
      layer.id = "al5d-page-lost";
      layer.setAttribute("role", "alert");
      layer.dataset.at = String(Date.now());  // when the page said it (epoch ms)
      layer.style.cssText = "position:fixed;inset:0;z-index:250;background:rgba(73,80,87,.45);"
        + "display:flex;align-items:flex-start;justify-content:center;padding-top:12vh";
      const text = document.createElement("div");
      text.style.cssText = "background:#c92a2a;color:#fff;padding:.8em 1.2em;font-weight:700;"
        + "border-radius:6px;max-width:32em;font-family:sans-serif";
      layer.appendChild(text);
      document.body.appendChild(layer);
    }}
    layer.firstChild.textContent = `No contact with the web view for ${{Math.floor(age)}} s: `
      + "what this page shows is old and its controls are off. STOP is still sent; it "
      + "stops the arm if it reaches the web view.";
  }}, 100);
}}"""


def pulse_html(beat: int) -> str:
    """The element the page's watchdog watches (`PAGE_WATCH_JS`), at beat `beat`; it carries
    the watchdog's script."""
    script = html.escape(PAGE_WATCH_JS, quote=True)
    return f'<img id="al5d-pulse" data-n="{beat}" alt="" hidden src="{PIXEL}" onload="{script}">'


#: The page's words for the server's states where the server's are not plain English.
STATE_WORDS = {"shutting_down": "shutting down", "ended": "server ended", NO_CONTACT: "no contact"}


def state_html(state: str) -> str:
    colour = STATE_COLOURS.get(state, "#495057")
    word = STATE_WORDS.get(state, state)
    # Two words or a long one: smaller, and wrapped rather than clipped by the panel.
    size = "2.4em" if len(word) <= 9 else "1.6em"
    return (
        f'<div id="al5d-state" style="font-size:{size};font-weight:800;text-align:center;'
        f"letter-spacing:0.06em;overflow-wrap:anywhere;line-height:1.15;"
        f'color:{colour}">{html.escape(word.upper())}</div>'
    )


def banner_html(text: str) -> str:
    return (
        '<div id="al5d-banner" style="background:#c92a2a;color:#fff;padding:0.6em 0.8em;'
        f'font-weight:700;border-radius:4px;margin:0 0.6em">{html.escape(text)}</div>'
    )


#: The element of the sliders' status (tests find it by this id).
JOINTS_STATUS = "al5d-joints-status"
#: Under STOP: what became of the page's last STOP or RELEASE.
ANSWER_STATUS = "al5d-answer"


def status_html(text: str, ok: bool | None, ident: str = "al5d-target-status") -> str:
    colour = {True: "#2b8a3e", False: "#c92a2a", None: "#495057"}[ok]
    return (
        f'<div id="{ident}" style="color:{colour};font-size:0.85em;'
        f'overflow-wrap:anywhere;padding:0 0.6em">{html.escape(text)}</div>'
    )


def tool_html(tool_mm: Vec3, rate: int, target: str) -> str:
    x, y, z = tool_mm
    ghost = f'<br><span id="al5d-ghost">target: {html.escape(target)}</span>' if target else ""
    return (
        '<div id="al5d-tool" style="font-family:monospace;font-size:0.85em;'
        f'padding:0 0.6em">tool (mm) x {x:.1f} y {y:.1f} z {z:.1f}<br>'
        f"joint states {rate}/s{ghost}</div>"
    )


class Panel:
    """STOP, and the side panel's widgets; every control but STOP can be turned off."""

    def __init__(self, server: viser.ViserServer, config: ArmConfig, title: str) -> None:
        self.config = config
        self.gui = gui = server.gui
        gui.configure_theme(show_share_button=False, show_logo=False, control_width="large")
        gui.set_panel_label(title)
        gui.main_panel.dock_right()
        self.stop_window = gui.add_panel(order=-1)
        with self.stop_window.add_tab("Emergency stop", viser.Icon.HAND_STOP):
            gui.add_html(PAGE_STYLE)
            self.stop = gui.add_button(
                "STOP", color="red", icon=viser.Icon.HAND_STOP, hint="emergency stop (any state)"
            )
            gui.add_html(phone_style(self.stop._impl.uuid))
            #: What became of the page's last STOP or RELEASE (`Page.on_answer`).
            self.answer_html = gui.add_html("")
            gui.add_html(names_html())
            #: In STOP's window: always drawn, whatever tab or section the panel shows.
            self.pulse = gui.add_html(pulse_html(0))
        self.stop_window.float(x=STOP_MARGIN_PX, y=-STOP_MARGIN_PX, width=STOP_WIDTH_PX)
        self.stop_window.expand()  # a phone's sheet draws it as a section, collapsed
        self.state_html = gui.add_html(state_html("unknown"))
        self.banner = gui.add_html(banner_html("waiting for the server..."))
        self.release = gui.add_button("release", icon=viser.Icon.LOCK_OPEN, visible=False)
        self.tool_html = gui.add_html("")
        self.last_html = gui.add_html("")
        #: The tabs; the Teach tab (teach.py) and the Calibrate tab (calibrate.py) are added.
        self.tabs = tabs = gui.add_tab_group()
        self.joints_tab = tabs.add_tab("Joints", viser.Icon.ADJUSTMENTS)
        with self.joints_tab:
            self.sliders: dict[str, Any] = {}
            for name, joint in config.joints.items():
                lo, hi = joint.range_deg
                self.sliders[name] = gui.add_slider(
                    name, min=float(lo), max=float(hi), step=0.5, initial_value=min(max(0, lo), hi)
                )
            self.time_ms_number = gui.add_number(
                "time (ms)",
                initial_value=0,
                min=0,
                max=config.server.max_move_time_ms,
                step=100,
                hint="0: as fast as the servos allow",
            )
            self.presets = gui.add_button_group("presets", tuple(config.presets), disabled=True)
            # The sliders' move judged as the server will judge it, while they are dragged.
            self.joints_status = gui.add_html(
                status_html("drag a slider to move", None, JOINTS_STATUS)
            )
        self.presets_disabled = True  # the handle always says False
        self._on_preset: Callable[[Any], None] | None = None
        with tabs.add_tab("Target", viser.Icon.TARGET):
            self.xyz_numbers: dict[str, Any] = {
                axis: gui.add_number(f"{axis} (mm)", initial_value=0.0, step=1.0)
                for axis in ("x", "y", "z")
            }
            #: Empty: the server picks (the reachable pitch nearest the current; the wrist
            #: rotate and the gripper stay).
            self.tool_texts: dict[str, Any] = {
                key: gui.add_text(label, initial_value="", hint=hint)
                for key, (label, hint) in TOOL_FIELDS.items()
            }
            self.target_time_number = gui.add_number(
                "move time (ms)",
                initial_value=0,
                min=0,
                max=config.server.max_move_time_ms,
                step=100,
                hint="0: as fast as the servos allow",
            )
            self.line_checkbox = gui.add_checkbox(
                "straight line", initial_value=False, hint="path: the tool on a straight line"
            )
            self.move_to = gui.add_button("move to", icon=viser.Icon.ARROW_RIGHT)
            self.target_status = gui.add_html(
                status_html("drag the gizmo at the tool, or type a point", None)
            )
        with tabs.add_tab("History", viser.Icon.HISTORY):
            self.plot = gui.add_uplot(
                _empty_series(),
                (
                    uplot.Series(label="s"),
                    *(
                        uplot.Series(label=j, stroke=c, width=1.5)
                        for j, c in zip(JOINTS, JOINT_COLOURS, strict=True)
                    ),
                ),
                title="joint angles (deg), last 10 s",
                scales={"x": {"time": False}},
                aspect=1.4,
            )
            self.outcomes_html = gui.add_html("")
        #: Every control but STOP: what a lost server turns off.
        self.controls: list[Any] = [
            self.release,
            *self.sliders.values(),
            self.time_ms_number,
            *self.xyz_numbers.values(),
            *self.tool_texts.values(),
            self.target_time_number,
            self.line_checkbox,
            self.move_to,
        ]
        self.set_enabled(False)

    # -- showing ---------------------------------------------------------------------

    def show_state(self, state: str) -> bool:
        """The state shown; False if it was shown already (nothing sent)."""
        content = state_html(state)
        if self.state_html.content == content:
            return False
        self.state_html.content = content
        # Nothing to release in any other state: a button there would only be refused.
        self.release.visible = state in RELEASABLE
        return True

    def beat(self, beat: int) -> None:
        """The pulse the page's watchdog waits for."""
        self.pulse.content = pulse_html(beat)

    def show_lost(self, text: str | None) -> None:
        """The red banner with `text`, or none."""
        if text is not None:
            self.banner.content = banner_html(text)
        self.banner.visible = text is not None

    def set_enabled(self, enabled: bool) -> None:
        for control in self.controls:
            control.disabled = not enabled
        if self.presets_disabled == enabled:
            self._rebuild_presets(disabled=not enabled)

    def on_preset(self, handler: Callable[[Any], None]) -> None:
        self._on_preset = handler
        self.presets.on_click(handler)

    def _rebuild_presets(self, disabled: bool) -> None:
        """The preset buttons again, in their place: viser 1.1.1 disables a button group
        only when it is made (its handle refuses `disabled = True`)."""
        order = self.presets.order
        self.presets.remove()
        with self.joints_tab:
            self.presets = self.gui.add_button_group(
                "presets", tuple(self.config.presets), disabled=disabled, order=order
            )
        self.presets_disabled = disabled
        if self._on_preset is not None:
            self.presets.on_click(self._on_preset)

    def show_tool(self, tool_mm: Vec3, rate: int, target: str) -> None:
        self.tool_html.content = tool_html(tool_mm, rate, target)

    def show_outcomes(self, outcomes: OutcomeLog) -> None:
        text = outcomes.html()
        pad = '<div style="padding:0 0.6em">{}</div>'
        self.outcomes_html.content = pad.format(text)
        last = text.split("</div>", 1)[0] + "</div>"
        self.last_html.content = pad.format(last) if outcomes.items else ""

    def show_status(self, text: str, ok: bool | None) -> None:
        self.target_status.content = status_html(text, ok)

    def show_answer(self, text: str, ok: bool | None) -> None:
        self.answer_html.content = status_html(text, ok, ANSWER_STATUS)

    def show_joints_status(self, text: str, ok: bool | None) -> None:
        self.joints_status.content = status_html(text, ok, JOINTS_STATUS)

    def show_plot(self, series: tuple[npt.NDArray[np.float64], ...]) -> None:
        self.plot.data = series

    def set_slider(self, joint: str, degrees: float) -> None:
        """The slider at `degrees` (its step, within its range) unless it is there already.
        Programmatic: the page's own handler sees no client and sends nothing."""
        slider = self.sliders[joint]
        lo, hi = self.config.joints[joint].range_deg
        value = min(max(round(degrees * 2) / 2, lo), hi)
        if abs(slider.value - value) > 0.25:
            slider.value = value

    def set_xyz(self, xyz_mm: Sequence[float]) -> None:
        for axis, v in zip("xyz", xyz_mm, strict=True):
            self.xyz_numbers[axis].value = round(v, 1)

    # -- reading -------------------------------------------------------------------

    def xyz(self) -> tuple[float, float, float]:
        # + 0.0: a field set from the tool's readout can hold -0.0, said "y -0".
        x, y, z = (float(self.xyz_numbers[a].value) + 0.0 for a in "xyz")
        return (x, y, z)

    def time_ms(self) -> int | None:
        """The Joints tab's move time (None: 0, as fast as the servos allow).

        Raises:
            TimeNotTaken: the box holds what it cannot (only a crafted update puts it there).
        """
        return _box_ms(self.time_ms_number)

    def target_time_ms(self) -> int | None:
        """The Target tab's move time, as `time_ms`."""
        return _box_ms(self.target_time_number)

    def tool_fields(self) -> dict[str, float | None] | str:
        """The Target tab's pitch, roll and gripper (None: empty), or what is wrong with one."""
        out: dict[str, float | None] = {}
        for key, text in self.tool_texts.items():
            value = str(text.value).strip()
            try:
                number = float(value) if value else None
            except ValueError:
                number = math.nan
            if number is not None and not math.isfinite(number):
                return f"{TOOL_FIELDS[key][0]}: {value!r} is not a number"
            out[key] = number
        return out

    def line(self) -> bool:
        return bool(self.line_checkbox.value)


def _empty_series() -> tuple[npt.NDArray[np.float64], ...]:
    nothing = np.array([np.nan, np.nan])
    return (np.array([-10.0, 0.0]), *(nothing for _ in JOINTS))
