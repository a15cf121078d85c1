"""`morphmimic studio`: a local web page that runs a trained controller live in 3-D and lets you
change it while it moves: the body (Won & Lee 2019's interactive character creation: shape
sliders that morph the walking character), the checkpoint, agent, clip and, for the executor,
UniCon 2020's schedulers (keyboard steering, clip stitching), projectiles and mass.

    morphmimic studio                                   # lower_biped-20M on http://127.0.0.1:8080
    morphmimic studio --checkpoint learner/pretrained/executor --port 8090
    morphmimic studio --host 0.0.0.0 --allow-origin http://myhost:8080   # share it on the network
    morphmimic studio --seconds 30                      # stops by itself (tests, demos)
    morphmimic studio --checkpoint executor --screenshot runs/studio.png   # headless Chromium: a PNG
    morphmimic studio --checkpoint runs/executor-shape --clip humanoid3d_walk --shape height=1.3   # opens on that body

Library: the page is viser (1.x: a three.js client served by Python over a websocket, with GUI
panels, uPlot plots and hotkeys), and the 3-D view is mjviser's `ViserMujocoScene` (by the mjlab
authors), which turns any `MjModel`'s geoms into batched viser meshes and moves them from `MjData`
each frame. We chose mjviser over hand-writing that geom-to-mesh layer on plain viser because it
already covers every geom type, materials, the floor grid and camera tracking; its own `Viewer`
owns the simulation loop (pacing, pause), so we use only its scene, and since it bakes geom sizes
at construction, a morph (a recompiled model) rebuilds the scene (studio_scene.py).

How it runs (studio_core.py): a background thread steps the session at real time; every control
on the page only queues a command that the thread applies between two steps, and a command that
fails (an out-of-range value, an unknown clip, a missing scheduler) is counted and shown in the
status line while the simulation keeps going. With no browser connected the loop does not
step (and the panel is not refreshed): an unwatched studio idles (measured over 20 s: 29% of a core
before, 0.1% after); the simulation goes on when a page connects. The status line names the
checkpoint as it was typed or picked (`executor`, not its run's name), and with the video
scheduler shows the packets received and rejected by reason.

Only the studio's own page may open its websocket (origin_guard.py): a page of another origin
is refused at the handshake, unless named with `--allow-origin` (remote use by a host name).

`--screenshot PNG` opens the page in headless Chromium (learner/live/chromium.py; `apt-get
install chromium`), waits until the scene shows the character and it has moved for
`--screenshot-after` seconds, saves the PNG and exits (`morphmimic studio --screenshot
docs/img/studio.png` made the README's picture).
"""

from __future__ import annotations

import html
import logging
import sys
import threading
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, ClassVar

import numpy as np
import torch
import tyro
import viser

from common.config_limits import PORT, Limit, above, at_least, check_limits, validated
from learner.cli_options import parse_options
from learner.live.chromium import DISMISS_NOTIFICATIONS_JS, Chromium, character_pixels, find_chromium
from learner.live.origin_guard import OriginPolicy, guarded_viser_server, parse_origin
from learner.live.session import AGENTS, SessionOptions
from learner.live.studio_core import KEYS, SCHEDULERS, StudioCore, pretrained_checkpoints
from learner.live.studio_scene import CharacterScene

DEFAULT_CHECKPOINT = "lower_biped-20M"
"""Trained on the current body (the slimmer shank) and stays up through a full-strength morph."""
REFRESH_S = 0.25
"""How often the status line, the plots and the table are refreshed."""
PLOT_POINTS = 240
COLORS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf")
HOTKEYS = {"arrowleft": "left", "arrowright": "right", "arrowup": "faster", "arrowdown": "slower", "S": "stop"}


class StudioGui:
    """The control panel: every callback only queues a command on the core."""

    def __init__(self, server: viser.ViserServer, core: StudioCore, scene: CharacterScene, checkpoints: dict[str, str]):
        self.server, self.core, self.scene = server, core, scene
        self.checkpoints = dict(checkpoints)
        self._quiet = threading.local()
        self._generation = -1
        self._touched: dict[str, float] = {}
        self._shape_sliders: dict[str, Any] = {}
        self._terms_plot = self._shape_plot = None
        self._terms_names: tuple[str, ...] = ()
        self._stop = threading.Event()
        self._refresh_lock = threading.Lock()  # the panel's thread and a direct caller (tests) may refresh at once
        self._thread: threading.Thread | None = None
        gui = server.gui
        gui.configure_theme(control_width="large", show_share_button=False, brand_color=(46, 94, 170))
        self.status = gui.add_markdown("starting...")
        self.error_line = gui.add_html("")
        tabs = gui.add_tab_group()
        current = self._checkpoint_name(core.checkpoint)  # NOTE: first: it adds a checkpoint that is not shipped
        with tabs.add_tab("Run", icon=viser.Icon.PLAYER_PLAY):
            self.checkpoint = gui.add_dropdown("Checkpoint", options=list(self.checkpoints), initial_value=current,
                                               hint="a shipped checkpoint (learner/pretrained/*); loading takes a few seconds")
            self.agent = gui.add_dropdown("Agent", options=list(AGENTS), initial_value=core.session.agent,
                                          hint="the policy (mean action), or zero / random actions for comparison")
            self.clip = gui.add_dropdown("Clip", options=list(core.session.clips) or ["-"])
            self.scheduler = gui.add_dropdown("Scheduler", options=list(SCHEDULERS), initial_value="dataset",
                                              hint="where the executor's target frames come from (UniCon's schedulers)")
            self.pause = gui.add_checkbox("Pause", initial_value=False)
            self.follow = gui.add_checkbox("Camera follow", initial_value=True, hint="keep the character centred")
            self.reset_button = gui.add_button("Reset", icon=viser.Icon.REFRESH)
            with gui.add_folder("Perturb", expand_by_default=False):
                self.speed = gui.add_slider("Projectile m/s", min=1.0, max=30.0, step=0.5, initial_value=10.0,
                                            hint="the executor: a 2 kg ball; a shape controller: a push of the same momentum")
                self.throw_button = gui.add_button("Throw projectile", icon=viser.Icon.BALL_BASKETBALL)
                self.mass = gui.add_slider("Mass factor", min=0.5, max=2.0, step=0.05, initial_value=1.0,
                                           hint="every body heavier or lighter (UniCon Table 2)")
        with tabs.add_tab("Body", icon=viser.Icon.MAN):
            self.body_note = gui.add_markdown("")
            self.body_preset = gui.add_dropdown("Body preset", options=["base"],
                                                hint="a named body (Won & Lee's Figure 1): morphs to it while moving")
            self.shape_text = gui.add_text("NAME=VALUE", initial_value="global_z=1.2",
                                           hint="type shape values (several: spaces between); out-of-range ones are refused")
            self.shape_apply = gui.add_button("Apply typed values")
            self.shape_folder = gui.add_folder("Shape")
        with tabs.add_tab("Steer", icon=viser.Icon.KEYBOARD):
            self.steer_note = gui.add_markdown("")
            self.keys = gui.add_button_group("Keyboard", options=list(KEYS))
            self.style = gui.add_dropdown("Style", options=keyboard_styles(), hint="the keyboard scheduler's locomotion styles")
            self.style_button = gui.add_button("Set style")
            self.queue_clip = gui.add_dropdown("Stitch clip", options=list(core.session.clips) or ["-"])
            self.queue_button = gui.add_button("Queue clip", icon=viser.Icon.PLAYLIST_ADD)
        self.plots = gui.add_folder("Plots")
        with self.plots:
            self.table = gui.add_markdown("")
        self._wire()

    # ---- callbacks: enqueue only ----

    def _checkpoint_name(self, path: str) -> str:
        for name, p in self.checkpoints.items():
            if Path(p).resolve() == Path(path).resolve():
                return name
        self.checkpoints[str(path)] = str(path)
        return str(path)

    def _user(self) -> bool:
        """False while the panel itself writes a control's value (no command then)."""
        return not getattr(self._quiet, "on", False)

    def _set_quietly(self, handle, **props: Any) -> None:
        self._quiet.on = True
        try:
            for k, v in props.items():
                setattr(handle, k, v)
        finally:
            self._quiet.on = False

    def _wire(self) -> None:
        core = self.core

        @self.checkpoint.on_update
        def _(_) -> None:
            if self._user():
                core.load(self.checkpoints[self.checkpoint.value], label=self.checkpoint.value)

        @self.agent.on_update
        def _(_) -> None:
            if self._user():
                core.set_agent(self.agent.value)

        @self.clip.on_update
        def _(_) -> None:
            if self._user():
                core.set_clip(self.clip.value)

        @self.scheduler.on_update
        def _(_) -> None:
            if self._user():
                core.use_scheduler(self.scheduler.value)

        @self.pause.on_update
        def _(_) -> None:
            if self._user():
                core.set_paused(self.pause.value)

        @self.follow.on_update
        def _(_) -> None:
            if self._user():
                s = core.session
                self.scene.set_follow(self.follow.value, np.array(s.env.data.xpos[s.root_body]))

        self.reset_button.on_click(lambda _: core.reset())
        self.throw_button.on_click(lambda _: core.throw(self.speed.value))

        @self.mass.on_update
        def _(_) -> None:
            if self._user():
                core.set_mass(self.mass.value)

        self.shape_apply.on_click(lambda _: core.set_shape_text(self.shape_text.value))

        @self.body_preset.on_update
        def _(_) -> None:
            if self._user():
                self.choose_body(self.body_preset.value)
        self.keys.on_click(lambda event: core.steer(event.target.value))
        self.style_button.on_click(lambda _: core.steer(f"style:{self.style.value}"))
        self.queue_button.on_click(lambda _: core.queue_clip(self.queue_clip.value))
        for hotkey, key in HOTKEYS.items():
            cmd = self.server.gui.add_command(f"Steer: {key}", description="keyboard scheduler (the executor)",
                                              hotkey=hotkey)
            cmd.on_trigger(lambda _, key=key: core.steer(key))
        self.server.gui.add_command("Pause / run", hotkey="P").on_trigger(
            lambda _: self._set_pause_from_key())

    def _set_pause_from_key(self) -> None:
        self.pause.value = not self.pause.value  # fires the checkbox's callback (a user action)

    def choose_body(self, label: str) -> None:
        """What picking a body preset does: morph to its shape values (the sliders follow)."""
        presets = self.core.session.body_presets()
        if label in presets:
            for name in presets[label]:
                self._touched.pop(name, None)
            self.core.set_shape(presets[label])

    def move_slider(self, name: str, value: float) -> None:
        """What dragging shape slider `name` does (the callback's command path)."""
        self._touched[name] = time.monotonic()
        self.core.set_shape({name: value})

    # ---- the session's controls (rebuilt when another session is loaded) ----

    def _rebuild_session_controls(self, snap: dict[str, Any]) -> None:
        s = self.core.session
        gui = self.server.gui
        executor = s.kind == "executor"
        clips = list(s.clips) or ["-"]
        current = self._checkpoint_name(self.core.checkpoint)
        self._set_quietly(self.checkpoint, options=list(self.checkpoints))
        self._set_quietly(self.checkpoint, value=current)
        self._set_quietly(self.agent, value=s.agent)
        self._set_quietly(self.clip, options=clips)
        self._set_quietly(self.clip, value=snap["clip"] if snap["clip"] in clips else clips[0])
        self._set_quietly(self.scheduler, value=self.core.scheduler_name, disabled=not executor)
        self._set_quietly(self.mass, value=1.0)
        self._set_quietly(self.queue_clip, options=clips)
        for h in (self.style_button, self.queue_button, self.queue_clip, self.style):  # NOTE: viser cannot disable a button group
            h.disabled = not executor
        self.steer_note.content = (
            "Keys (or the arrow keys, **S** stop) steer the executor through the keyboard scheduler; "
            "*Queue clip* stitches clips (the stitch scheduler). Both switch the scheduler on first use."
            if executor else f"*{self.core.label} is {KIND_TEXT.get(s.kind, 'a ' + s.kind + ' task')}: it "
                             f"{'reaches for a new target each episode' if s.kind == 'reach' else 'follows its own clip'}; "
                             "keyboard steering and stitching drive the executor.*")
        for slider in self._shape_sliders.values():
            slider.remove()
        self._shape_sliders = {}
        lo, hi = s.shape_box
        can = s.shape_can_change
        self.body_note.content = (
            (f"{len(s.shape_names)} shape parameters; dragging a slider morphs the body while it moves "
             "(Won & Lee 2019); its state is kept"
             + ("; the tracked clip is retargeted onto the new body at the same clip time (live while it tracks a clip "
                "or follows the keyboard; stitch and video refuse a change)." if s.kind == "executor" else ".")) if can else
            f"*{self.core.label} trains on one body: its shape cannot change (sliders disabled).*" if s.shape_names else
            f"*{self.core.label} has no shape parameters.*")
        self.shape_text.disabled = self.shape_apply.disabled = not can
        self._set_quietly(self.body_preset, options=list(s.body_presets()), value="base", disabled=not can)
        with self.shape_folder:
            for i, name in enumerate(s.shape_names):
                step = max(1e-3, round(float(hi[i] - lo[i]) / 100.0, 4)) if hi[i] > lo[i] else 0.01
                slider = gui.add_slider(name, min=float(lo[i]), max=float(max(hi[i], lo[i] + step)), step=step,
                                        initial_value=float(s.params[i]), disabled=not can)
                slider.on_update(lambda _, name=name, slider=slider: self._user() and self.move_slider(name, slider.value))
                self._shape_sliders[name] = slider
        for plot in (self._terms_plot, self._shape_plot):
            if plot is not None:
                plot.remove()
        self._terms_plot = self._shape_plot = None
        self._terms_names = ()
        if len(s.shape_names):
            x = np.arange(len(s.shape_names), dtype=float)
            with self.plots:
                self._shape_plot = gui.add_uplot(
                    (x, snap["shape"], np.asarray(lo, float), np.asarray(hi, float)),
                    ({"label": "parameter #"}, {"label": "shape", "stroke": "#2e5eaa", "width": 2, "points": {"show": True}},
                     {"label": "low", "stroke": "#aaaaaa", "dash": [4, 4]}, {"label": "high", "stroke": "#aaaaaa", "dash": [4, 4]}),
                    title="shape vector", scales={"x": {"time": False}}, aspect=2.0, order=2.0)
        self._generation = snap["generation"]

    def _terms_plot_for(self, names: tuple[str, ...]) -> None:
        if names == self._terms_names and self._terms_plot is not None:
            return
        if self._terms_plot is not None:
            self._terms_plot.remove()
        series = [{"label": "t (s)"}, {"label": "reward", "stroke": "#000000", "width": 2}]
        series += [{"label": n, "stroke": COLORS[i % len(COLORS)], "width": 1.5} for i, n in enumerate(names)]
        with self.plots:
            self._terms_plot = self.server.gui.add_uplot(
                tuple(np.zeros(2) for _ in series), tuple(series), title="reward and its terms (last 10 s)",
                scales={"x": {"time": False}}, aspect=1.6, order=1.0)
        self._terms_names = names

    # ---- refresh: the panel's thread ----

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="studio-gui", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)

    def _run(self) -> None:
        while not self._stop.is_set():
            if not self.server.get_clients():  # NOTE: nobody to show it to; a page that connects gets it within REFRESH_S
                self._stop.wait(REFRESH_S)
                continue
            try:
                self.refresh()
            except Exception:  # noqa: BLE001 - the panel must never stop; print and go on
                traceback.print_exc()
            self._stop.wait(REFRESH_S)

    def refresh(self) -> None:
        """Bring the panel up to the core's state; one caller at a time (viser's folders allow one
        `with` block each, and two callers rebuilding the session's controls at once raised)."""
        with self._refresh_lock:
            self._refresh()

    def _refresh(self) -> None:
        snap = self.core.snapshot()
        if snap["generation"] != self._generation:
            self._rebuild_session_controls(snap)
        self.status.content = status_markdown(snap)
        self.error_line.content = message_html(snap)
        self._set_quietly(self.scheduler, value=snap["scheduler"])
        self._set_quietly(self.pause, value=snap["paused"])
        now = time.monotonic()
        for i, (name, slider) in enumerate(self._shape_sliders.items()):
            v = float(snap["shape"][i])
            if abs(slider.value - v) > 1e-9 and now - self._touched.get(name, 0.0) > 1.0:
                self._set_quietly(slider, value=float(np.clip(v, slider.min, slider.max)))
        t = snap["t"]
        if len(t) >= 2:
            names = tuple(snap["terms"])
            self._terms_plot_for(names)
            idx = np.unique(np.linspace(0, len(t) - 1, min(len(t), PLOT_POINTS)).astype(int))
            ys = [snap["reward_hist"]] + [snap["terms"][n] for n in names]
            self._terms_plot.data = (t[idx],) + tuple(np.nan_to_num(y[idx]) for y in ys)
        if self._shape_plot is not None:
            x, _, lo, hi = self._shape_plot.data
            self._shape_plot.data = (x, snap["shape"], lo, hi)
        self.table.content = terms_table(snap)


def keyboard_styles() -> list[str]:
    """The keyboard scheduler's style names (walk, run, ...), or just walk and run when the
    schedulers are not in this checkout."""
    try:
        # lazy: optional: if the schedulers fail to load, the panel still opens (except below)
        from common.tasks.executor.schedulers.keyboard import locomotion_styles

        return list(locomotion_styles()) or ["walk", "run"]
    except Exception:  # noqa: BLE001 - the panel still opens; choosing a style reports the problem
        return ["walk", "run"]


KIND_TEXT = {"executor": "the executor", "shape": "a shape controller", "reach": "the reach arm"}
"""How the page names a task family."""


def status_markdown(snap: dict[str, Any]) -> str:
    what = KIND_TEXT.get(snap["kind"], snap["kind"]).split(" ", 1)[-1]
    parts = [f"**{snap['name']}** ({what})", f"agent {snap['agent']}", f"t {snap['time_s']:.1f} s",
             f"return {snap['return']:.1f}", snap.get("reset_text") or f"resets {snap['resets']}",
             f"mass x{snap['mass_factor']:.2f}"]
    if snap.get("distance_m") is not None:
        parts.append(f"fingertip {1000 * snap['distance_m']:.0f} mm from the target")
    if snap["kind"] == "executor":
        when = f" {snap['clip_time_s']:.1f} s" if snap.get("clip_time_s") is not None else ""
        parts.append(f"{snap['scheduler']}: {snap['clip'] or '-'}{when}")
    if snap.get("video"):
        parts.append(snap["video"].replace("*", "\\*"))
    if snap["paused"]:
        parts.append("**paused**")
    if snap["loading"]:
        parts.append(f"loading {snap['loading']}...")
    parts.append(f"**errors {snap['errors']}**")
    return " · ".join(parts)


def message_html(snap: dict[str, Any]) -> str:
    text = html.escape(snap["message"] or "", quote=False)
    if snap["message_is_error"]:
        return (f'<div id="studio-error" style="color:#b00020;font-size:0.85em;padding:0 1em">'
                f'&#9888; error {snap["errors"]}: {text}</div>')
    return f'<div id="studio-message" style="color:#555;font-size:0.85em;padding:0 1em">{text}</div>'


def terms_table(snap: dict[str, Any]) -> str:
    if not snap["terms"]:
        return ""
    rows = ["| term | now | mean (10 s) |", "|---|---:|---:|",
            f"| reward | {snap['reward']:.3f} | {np.nanmean(snap['reward_hist']):.3f} |"]
    rows += [f"| {n} | {v[-1]:.3f} | {np.nanmean(v):.3f} |" for n, v in snap["terms"].items()]
    return "\n".join(rows)


class _QuietHandshakes(logging.Filter):
    """Browsers open speculative connections that close before a request: websockets logs each
    as an error with a traceback; nothing is wrong, so those records are dropped."""

    def filter(self, record: logging.LogRecord) -> bool:
        return "opening handshake failed" not in record.getMessage()


class Studio:
    """The web studio: a viser server, the 3-D scene, the panel and the running core."""

    def __init__(self, checkpoint: str | None = None, host: str = "127.0.0.1", port: int = 8080,
                 agent: str = "policy", clip: str | None = None, seed: int = 0, verbose: bool = False,
                 idle_unwatched: bool = True, allow_origins: tuple[str, ...] = (), shape: dict[str, float] | None = None):
        """`allow_origins`: web origins besides the studio's own page whose websockets are
        accepted (`origin_guard.OriginPolicy`); ValueError names a malformed one. `shape`: the
        body the session opens with (as `play --shape`); the sliders start there."""
        self.origins = OriginPolicy(allow_origins)
        server_log = logging.getLogger("websockets.server")
        if not any(isinstance(f, _QuietHandshakes) for f in server_log.filters):
            server_log.addFilter(_QuietHandshakes())
        checkpoints = pretrained_checkpoints()
        label = checkpoint or DEFAULT_CHECKPOINT
        self.core = StudioCore(checkpoints.get(label, label), agent=agent, clip=clip, seed=seed, label=label, shape=shape)
        self.server = guarded_viser_server(self.origins, host=host, port=port, label="morphmimic studio", verbose=verbose)
        if idle_unwatched:  # NOTE: after the server exists; until then nobody can watch
            self.core.watched = lambda: bool(self.server.get_clients())
        self.scene = CharacterScene(self.server)
        self.core.on_frame = lambda core: self.scene.update(core.session)
        self.gui = StudioGui(self.server, self.core, self.scene, checkpoints)

    @property
    def url(self) -> str:
        host = self.server.get_host()
        return f"http://{'127.0.0.1' if host in ('0.0.0.0', '') else host}:{self.server.get_port()}/"

    def start(self) -> "Studio":
        self.gui.refresh()
        self.core.start()
        self.gui.start()
        return self

    def stop(self) -> None:
        self.gui.stop()
        self.core.stop()
        self.server.stop()

    def __enter__(self) -> "Studio":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


PROG = "morphmimic studio"
SCREENSHOT_TIMEOUT_S = 90.0
"""Software WebGL on 2 busy cores takes tens of seconds to draw the first frame."""


def take_screenshot(studio: Studio, path: Path, size: tuple[int, int] = (1280, 800), after_s: float = 3.0,
                    timeout_s: float = SCREENSHOT_TIMEOUT_S) -> None:
    """Open the studio's page in headless Chromium, wait until the scene shows the character
    (its colour in the 3-D view, `chromium.character_pixels`) and it has stepped `after_s`
    simulated seconds, close the notifications and save the page as a PNG. RuntimeError when
    Chromium is missing or the scene does not show within `timeout_s`."""
    if find_chromium() is None:
        raise RuntimeError("needs chromium (apt-get install chromium)")
    end = time.monotonic() + timeout_s
    with Chromium(studio.url, *size) as browser:
        img = browser.screenshot()
        while character_pixels(img) < 400:
            if time.monotonic() > end:
                raise RuntimeError(f"the scene did not show the character within {timeout_s:g} s")
            time.sleep(0.5)
            img = browser.screenshot()
        steps, dt = studio.core.loop_steps, studio.core.session.env.dt
        while studio.core.loop_steps < steps + after_s / dt and time.monotonic() < end:
            time.sleep(0.2)
        browser.evaluate(DISMISS_NOTIFICATIONS_JS)
        time.sleep(1.0)
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        browser.screenshot_png(path)


@validated
@dataclass(kw_only=True)
class StudioOptions(SessionOptions):
    checkpoint: str = DEFAULT_CHECKPOINT
    """A shipped checkpoint name (listed above) or a checkpoint path."""
    host: str = "127.0.0.1"
    """Address to serve on (0.0.0.0: share it on the network)."""
    port: int = 8080
    """Port (taken: the next free one is used and printed; 0: any)."""
    allow_origin: tuple[str, ...] = ()
    """Web origins (http://host:port) whose pages may open the studio besides its own; others are refused."""
    seconds: float | None = None
    """Stop by itself after this many seconds."""
    screenshot: Path | None = None
    """Open the page in headless Chromium, wait until the scene shows the character, save this PNG and exit."""
    screenshot_after: float = 3.0
    """--screenshot: seconds the character moves (after the scene shows) before the picture."""
    screenshot_size: Annotated[tuple[int, int], tyro.conf.arg(metavar="W H")] = (1280, 800)
    """--screenshot: the page's size in pixels."""

    LIMITS: ClassVar[dict[str, Limit]] = {**SessionOptions.LIMITS, "port": PORT, "seconds": above(0),
                                          "screenshot_after": at_least(0)}

    def validate(self) -> None:
        check_limits(self)
        for origin in self.allow_origin:
            parse_origin(origin)


def main(argv: list[str]) -> int:
    description = f"{__doc__}\nshipped checkpoints: {', '.join(pretrained_checkpoints())}"
    args = parse_options(StudioOptions, argv, prog=PROG, description=description)

    torch.set_num_threads(1)  # NOTE: one small MLP per step: more threads only fight the server's
    try:
        studio = Studio(args.checkpoint, host=args.host, port=args.port, agent=args.agent, clip=args.clip, seed=args.seed,
                        allow_origins=args.allow_origin, shape=dict(args.shape) or None)
    except (ValueError, FileNotFoundError, SystemExit) as exc:  # NOTE: checkpoint.load_trained exits with a message on a bad checkpoint
        print(f"{PROG}: {exc}", file=sys.stderr)
        return 2
    studio.start()
    if args.screenshot is not None:
        try:
            take_screenshot(studio, args.screenshot, args.screenshot_size, args.screenshot_after)
        except (RuntimeError, TimeoutError) as exc:  # NOTE: TimeoutError: Chromium's DevTools did not answer (a busy machine)
            print(f"{PROG}: --screenshot: {'chromium did not answer: ' if isinstance(exc, TimeoutError) else ''}{exc}",
                  file=sys.stderr)
            return 2
        finally:
            studio.stop()
        print(f"[studio] wrote {args.screenshot}: {args.checkpoint} in the page at {args.screenshot_size[0]}x{args.screenshot_size[1]}", flush=True)
        return 0
    print(f"[studio] {studio.core.label} at {studio.url}  (Ctrl-C stops)", flush=True)
    end = time.monotonic() + args.seconds if args.seconds else None
    try:
        while end is None or time.monotonic() < end:
            time.sleep(0.2 if end is None else max(0.0, min(0.2, end - time.monotonic())))
    except KeyboardInterrupt:
        pass
    finally:
        studio.stop()
    snap = studio.core.snapshot()
    print(f"[studio] stopped: {snap['loop_steps']} steps, {snap['errors']} errors", flush=True)
    return 0
