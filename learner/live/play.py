"""`morphmimic play`: run any checkpoint (a shape controller or the executor) in real time, or
render it to an H.264 video, with the zero-action and random-action agents for comparison.

    morphmimic play --checkpoint learner/pretrained/lower_biped --seconds 10
    morphmimic play --checkpoint learner/pretrained/lower_biped --shape global_z=1.3 --out tall.mp4
    morphmimic play --checkpoint learner/pretrained/executor --clip humanoid3d_walk --out walk.mp4
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

import argparse
import math
import sys
import time
from pathlib import Path
from typing import Any


from learner.evaluation import cli_args
from learner.live.session import AGENTS, LiveSession

SCHEDULERS = ("dataset", "stitch", "keyboard", "video")


def _number_pair(text: str, sep: str, number_at: int) -> tuple[str, float] | None:
    """(the word, the finite number) of `text` split once at `sep`, the number at position
    `number_at` (0 or 1); None when that does not parse."""
    parts = text.split(sep, 1)
    if len(parts) != 2 or not parts[0] or not parts[1]:
        return None
    try:
        value = float(parts[number_at])
    except ValueError:
        return None
    return (parts[1 - number_at], value) if math.isfinite(value) else None


def shape_value(text: str) -> tuple[str, float]:
    """argparse type: NAME=VALUE."""
    pair = _number_pair(text, "=", 1)
    if pair is None:
        raise argparse.ArgumentTypeError(f"{text!r} is not NAME=VALUE with a finite number (e.g. global_z=1.2)")
    return pair


def timed_key(text: str) -> tuple[float, str]:
    """argparse type: SECONDS:KEY."""
    pair = _number_pair(text, ":", 0)
    if pair is None or pair[1] < 0:
        raise argparse.ArgumentTypeError(f"{text!r} is not SECONDS:KEY with seconds >= 0 (e.g. 2.5:left)")
    return pair[1], pair[0]


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="morphmimic play", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--checkpoint", required=True, help="a checkpoint directory, state.pt, run directory or learner/pretrained/<name>")
    p.add_argument("--agent", choices=AGENTS, default="policy", help="who acts (zero and random: for comparison)")
    p.add_argument("--seconds", type=cli_args.positive_float, default=10.0, help="simulated seconds to run")
    p.add_argument("--speed", type=cli_args.positive_float, default=1.0, help="playback speed: simulated seconds per real (or video) second")
    p.add_argument("--shape", type=shape_value, nargs="*", default=[], metavar="NAME=VALUE",
                   help="shape parameters of a shape controller (morphmimic character PRESET --list names them)")
    p.add_argument("--clip", default=None, help="the clip to follow (the executor: any humanoid clip)")
    p.add_argument("--scheduler", choices=SCHEDULERS, default="dataset", help="where the executor's target frames come from")
    p.add_argument("--stitch", nargs="*", default=[], metavar="CLIP", help="stitch: the clips to play one after the other")
    p.add_argument("--keys", type=timed_key, nargs="*", default=[], metavar="SECONDS:KEY",
                   help="keyboard: timed commands (left, right, faster, slower, stop, style:<name>)")
    p.add_argument("--video-port", type=cli_args.port, default=0, help="video: the UDP port to listen on (0: any free one, printed)")
    p.add_argument("--video-host", default="127.0.0.1", help="video: the address to listen on")
    p.add_argument("--seed", type=cli_args.seed, default=0)
    p.add_argument("--out", type=Path, default=None, help="render to this .mp4 (H.264) instead of running in real time")
    p.add_argument("--fps", type=cli_args.positive_float, default=30.0, help="frames per second of the video")
    p.add_argument("--width", type=cli_args.positive_int, default=640)
    p.add_argument("--height", type=cli_args.positive_int, default=480)
    p.add_argument("--viewer", action="store_true", help="open MuJoCo's viewer window (needs a display)")
    return p


def make_session(args: argparse.Namespace) -> tuple[LiveSession, Any]:
    """The session `args` describe, with its scheduler in place (None: the task's own)."""
    session = LiveSession(args.checkpoint, agent=args.agent, clip=args.clip, shape=dict(args.shape) or None, seed=args.seed)
    scheduler = None
    if args.scheduler != "dataset" or args.stitch or args.keys:
        if session.kind != "executor":
            raise ValueError(f"--scheduler {args.scheduler}: schedulers drive the executor; "
                             f"{session.loaded.name} is a shape controller that follows its own clip")
        from common.tasks.executor.schedulers.factory import make_scheduler

        options = {"stitch": {"clips": tuple(args.stitch)}, "keyboard": {"script": tuple(args.keys)},
                   "video": {"host": args.video_host, "port": args.video_port}}.get(args.scheduler, {})
        scheduler = make_scheduler(args.scheduler, session.env, **options)
        session.use_scheduler(scheduler)
        if args.scheduler == "video":
            print(f"[play] video scheduler listening on udp://{args.video_host}:{scheduler.port}", flush=True)
    return session, scheduler


def status_line(session: LiveSession) -> str:
    last = session.last
    terms = " ".join(f"{k[:9]} {v:.2f}" for k, v in (last.get("terms") or {}).items())
    where = f" | {last['clip_id']} {last.get('clip_time_s', 0.0):.1f}s" if "clip_id" in last else ""
    return (f"[play] t {session.steps * session.env.dt:6.1f}s | return {session.episode_return:8.2f} | resets {session.resets}"
            f"{where} | {terms}")


def run_realtime(session: LiveSession, seconds: float, speed: float, viewer: bool = False) -> None:
    """Step in real time x `speed`; a status line a second (or MuJoCo's viewer)."""
    dt = session.env.dt
    steps = int(round(seconds / dt))
    handle = None
    if viewer:
        import mujoco.viewer

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
    import imageio.v2 as imageio

    from learner.evaluation.shape.plots import FollowRenderer

    frames = int(round(seconds / speed * fps))
    dt = session.env.dt
    path.parent.mkdir(parents=True, exist_ok=True)
    renderer = FollowRenderer(width, height)
    writer = imageio.get_writer(str(path), fps=fps, codec="libx264", quality=7, macro_block_size=8,
                                ffmpeg_log_level="error", output_params=["-pix_fmt", "yuv420p"])
    try:
        sim_t = 0.0
        for f in range(frames):
            while sim_t < f * speed / fps - 1e-9:
                session.step()
                sim_t += dt
            writer.append_data(renderer.render(session.env, session.root_body, swimmer=session.is_swimmer))
    finally:
        writer.close()
        renderer.close()
    return frames


def main(argv: list[str]) -> int:
    args = build_parser().parse_args(argv)
    try:
        session, scheduler = make_session(args)
    except ValueError as exc:
        print(f"morphmimic play: {exc}", file=sys.stderr)
        return 2
    try:
        if args.out is not None:
            if args.out.suffix.lower() != ".mp4":
                print(f"morphmimic play: --out {args.out}: write an .mp4 (H.264)", file=sys.stderr)
                return 2
            n = render_video(session, args.out, args.seconds, args.speed, args.fps, args.width, args.height)
            print(f"[play] wrote {args.out}: {n} frames at {args.fps:g} fps ({args.seconds:g} s simulated at x{args.speed:g}); "
                  f"return {session.episode_return:.2f}, resets {session.resets}")
        else:
            run_realtime(session, args.seconds, args.speed, args.viewer)
            print(status_line(session))
    except KeyboardInterrupt:
        pass
    finally:
        if scheduler is not None and hasattr(scheduler, "close"):
            scheduler.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
