"""`morphmimic play`: run any checkpoint (a shape controller or the executor) in real time, or
render it to an H.264 video, with the zero-action and random-action agents for comparison.

    morphmimic play --checkpoint learner/pretrained/lower_biped --seconds 10
    morphmimic play --checkpoint learner/pretrained/lower_biped --shape global_z=1.3 --out tall.mp4
    morphmimic play --checkpoint learner/pretrained/executor --clip humanoid3d_walk --out walk.mp4
    morphmimic play --checkpoint runs/executor-shape --clip humanoid3d_walk --shape height=1.3 --out tall_walk.mp4
    morphmimic play --checkpoint learner/pretrained/executor --scheduler stitch \\
        --stitch humanoid3d_walk humanoid3d_run --out stitched.mp4
    morphmimic play --checkpoint learner/pretrained/executor --scheduler keyboard \\
        --keys 1:left 3:faster 5:right --out steer.mp4
    morphmimic play --checkpoint learner/pretrained/executor --scheduler video --video-port 9870
    morphmimic play --checkpoint learner/pretrained/lower_biped --agent random --out random.mp4

Without `--out` it runs in real time (`--speed` faster or slower) and prints one status line a
second; `--viewer` opens MuJoCo's own window instead (needs a display). With `--out` it renders
offscreen (MUJOCO_GL=egl or osmesa) to an H.264 MP4 through imageio-ffmpeg: `--fps` frames per
second of video, each `--speed` x as much simulated time, so the file has seconds x fps frames.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, ClassVar

import imageio.v2 as imageio

from common.config_limits import PORT, Limit, above, at_least, check_limits, validated
from common.tasks.executor.schedulers.factory import make_scheduler
from learner.cli_options import parse_options, value_list
from learner.live.session import LiveSession, Scheduler, SessionOptions, number_pair, video_status
from learner.progress import Progress

PROG = "morphmimic play"


def timed_key(text: str) -> tuple[float, str]:
    """'2.5:left' -> (2.5, 'left'); ValueError naming `text` when it is not SECONDS:KEY with
    seconds >= 0."""
    pair = number_pair(text, ":", 0)
    if pair is None or pair[1] < 0:
        raise ValueError(f"{text!r} is not SECONDS:KEY with seconds >= 0 (e.g. 2.5:left)")
    return pair[1], pair[0]


@validated
@dataclass(kw_only=True)
class PlayOptions(SessionOptions):
    checkpoint: str
    """A checkpoint directory, state.pt, run directory or learner/pretrained/<name>."""
    seconds: float = 10.0
    """Simulated seconds to run."""
    speed: float = 1.0
    """Playback speed: simulated seconds per real (or video) second."""
    scheduler: Scheduler = "dataset"
    """Where the executor's target frames come from."""
    stitch: Annotated[tuple[str, ...], value_list(str, "CLIP")] = ()
    """stitch: the clips to play one after the other."""
    keys: Annotated[tuple[tuple[float, str], ...], value_list(timed_key, "SECONDS:KEY", lambda k: f"{k[0]:g}:{k[1]}")] = ()
    """keyboard: timed commands (left, right, faster, slower, stop, style:<name>)."""
    video_port: int = 0
    """video: the UDP port to listen on (0: any free one, printed)."""
    video_host: str = "127.0.0.1"
    """video: the address to listen on."""
    out: Path | None = None
    """Render to this .mp4 (H.264) instead of running in real time."""
    fps: float = 30.0
    """Frames per second of the video."""
    width: int = 640
    """Video width in pixels."""
    height: int = 480
    """Video height in pixels."""
    viewer: bool = False
    """Open MuJoCo's viewer window (needs a display)."""

    LIMITS: ClassVar[dict[str, Limit]] = {**SessionOptions.LIMITS, "seconds": above(0), "speed": above(0),
                                          "video_port": PORT, "fps": above(0), "width": at_least(1),
                                          "height": at_least(1)}

    def validate(self) -> None:
        check_limits(self)


def make_session(args: PlayOptions) -> tuple[LiveSession, Any]:
    """The session `args` describe, with its scheduler in place (None: the task's own)."""
    session = LiveSession(args.checkpoint, agent=args.agent, clip=args.clip, shape=dict(args.shape) or None, seed=args.seed,
                          command="play")
    scheduler = None
    if args.scheduler != "dataset" or args.stitch or args.keys:
        if session.kind != "executor":
            follows = "follows its own clip" if session.kind == "shape" else "reaches for drawn targets"
            raise ValueError(f"--scheduler {args.scheduler}: schedulers drive the executor; "
                             f"{session.loaded.name} is a {session.kind} task that {follows}")

        options = {"stitch": {"clips": tuple(args.stitch)}, "keyboard": {"script": tuple(args.keys)},
                   "video": {"host": args.video_host, "port": args.video_port}}.get(args.scheduler, {})
        scheduler = make_scheduler(args.scheduler, session.env, **options)
        session.use_scheduler(scheduler)
        if args.scheduler == "video":
            print(f"[play] video scheduler listening on udp://{args.video_host}:{scheduler.port}", flush=True)
    return session, scheduler


def status_line(session: LiveSession) -> str:
    """One line: simulated time, the episode's return, the resets with the last one's cause,
    the clip tracked now and its time (the executor), the fingertip's distance to the target
    (reach), the last step's reward terms, and for video the packets received and rejected by reason."""
    last = session.last
    terms = " ".join(f"{k[:9]} {v:.2f}" for k, v in (last.get("terms") or {}).items())
    if "distance_m" in last:
        terms = " ".join([f"distance {1000 * last['distance_m']:.0f} mm"] + ([terms] if terms else []))
    tracking = session.tracking()
    where = f" | {tracking[0]} {tracking[1]:.1f}s" if tracking else ""
    video = video_status(session.scheduler)
    return (f"[play] t {session.steps * session.env.dt:6.1f}s | return {session.episode_return:8.2f} | {session.reset_text()}"
            f"{where} | {terms}" + (f" | {video}" if video else ""))


def run_realtime(session: LiveSession, seconds: float, speed: float, viewer: bool = False) -> None:
    """Step in real time x `speed`; a status line a second (or MuJoCo's viewer)."""
    dt = session.env.dt
    steps = int(round(seconds / dt))
    handle = None
    if viewer:
        import mujoco.viewer  # lazy: needs a display (GLFW), only with --viewer

        handle = mujoco.viewer.launch_passive(session.env.model, session.env.data)
    start = time.perf_counter()
    for k in range(1, steps + 1):
        session.step()
        if handle is not None:
            if not handle.is_running():
                break
            handle.sync()
        elif k % max(1, int(round(1.0 / dt))) == 0:
            print(status_line(session), flush=True)
        ahead = start + k * dt / speed - time.perf_counter()
        if ahead > 0:
            time.sleep(ahead)
    if handle is not None:
        handle.close()


def render_video(session: LiveSession, path: Path, seconds: float, speed: float, fps: float, width: int, height: int) -> int:
    """Write `seconds` of simulation at `speed` to an H.264 MP4 of `fps`; returns the frame count."""
    from learner.evaluation.shape.plots import FollowRenderer  # lazy: heavy (matplotlib), only when writing a video

    frames = int(round(seconds / speed * fps))
    dt = session.env.dt
    path.parent.mkdir(parents=True, exist_ok=True)
    renderer = FollowRenderer(width, height)
    writer = imageio.get_writer(str(path), fps=fps, codec="libx264", quality=7, macro_block_size=8,
                                ffmpeg_log_level="error", output_params=["-pix_fmt", "yuv420p"])
    try:
        sim_t = 0.0
        with Progress(f"[play] {path.name}", frames, "frames") as bar:
            for f in range(frames):
                while sim_t < f * speed / fps - 1e-9:
                    session.step()
                    sim_t += dt
                writer.append_data(renderer.render(session.env, session.root_body, swimmer=session.is_swimmer,
                                                   **session.view))
                bar.update()
    finally:
        writer.close()
        renderer.close()
    return frames


def main(argv: list[str]) -> int:
    args = parse_options(PlayOptions, argv, prog=PROG, description=__doc__)
    try:
        session, scheduler = make_session(args)
    except ValueError as exc:
        print(f"{PROG}: {exc}", file=sys.stderr)
        return 2
    try:
        if args.out is not None:
            if args.out.suffix.lower() != ".mp4":
                print(f"{PROG}: --out {args.out}: write an .mp4 (H.264)", file=sys.stderr)
                return 2
            n = render_video(session, args.out, args.seconds, args.speed, args.fps, args.width, args.height)
            video = video_status(scheduler)
            distance = session.last.get("distance_m")  # reach: where the fingertip ended
            print(f"[play] wrote {args.out}: {n} frames at {args.fps:g} fps ({args.seconds:g} s simulated at x{args.speed:g}); "
                  f"return {session.episode_return:.2f}, {session.reset_text()}" + (f"; {video}" if video else "")
                  + (f"; fingertip {1000 * distance:.0f} mm from the target" if distance is not None else ""))
        else:
            run_realtime(session, args.seconds, args.speed, args.viewer)
            print(status_line(session))
    except KeyboardInterrupt:
        pass
    finally:
        if scheduler is not None and hasattr(scheduler, "close"):
            scheduler.close()
    return 0
