"""UniCon 2020's run-time schedulers (METHOD.md B "Schedulers") on the real humanoid: dataset
(deviation reschedule), motion stitching, keyboard, video over real UDP sockets on 127.0.0.1,
and each one driving `ExecutorEnv` through `use_scheduler`."""

from __future__ import annotations

import math
import socket
import struct
import threading

import mujoco
import numpy as np
import pytest

from common.tasks.executor.schedulers import pose_packet

from learner.live import pose_sender
from common.tasks.base import TaskConfig
from common.tasks.body_config import BodyConfig
from common.tasks.executor.config import ExecutorConfig
from common.tasks.observations import heading, quat_to_mat
from common.tasks.executor.schedulers.pose_blend import PoseMath
from common.tasks.registry import make_env
from common.tasks.executor.schedulers.factory import SCHEDULERS, make_scheduler
from common.tasks.executor.schedulers.keyboard import KeyboardScheduler, locomotion_styles
from common.tasks.executor.schedulers.stitch import StitchScheduler
from common.tasks.executor.schedulers.video import VideoScheduler
from common.tasks.executor.schedulers.base import DatasetScheduler

CFG = TaskConfig(name="executor", control_hz=60.0, sim_hz=240.0, episode_s=5.0,
                 body=BodyConfig(parameterization="height_thickness", vary_shape=False), executor=ExecutorConfig())
WALK = "humanoid3d_walk"


@pytest.fixture(scope="module")
def env():
    return make_env(CFG, seed=0)


@pytest.fixture(scope="module")
def pm(env) -> PoseMath:
    return PoseMath(env.ref_model)


def body_positions(model: mujoco.MjModel, qpos: np.ndarray) -> np.ndarray:
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    mujoco.mj_kinematics(model, data)
    return data.xpos[1:].copy()


def check_frame(env, frame) -> None:
    assert frame.qpos.shape == (env.nq,) and frame.qvel.shape == (env.nv,)
    assert np.all(np.isfinite(frame.qpos)) and np.all(np.isfinite(frame.qvel))
    quats = frame.qpos[PoseMath(env.ref_model).quat_cols]
    np.testing.assert_allclose(np.linalg.norm(quats, axis=1), 1.0, atol=1e-6)


def send_now(port: int, positions: np.ndarray, t0: float = 0.0, fps: float = 60.0) -> None:
    """Send frames [T, J, 3] at once (timestamps t0 + k / fps), not paced."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        for k, p in enumerate(positions):
            sock.sendto(pose_packet.encode(k, t0 + k / fps, p), ("127.0.0.1", port))


def walk_positions(seconds: float, fps: float = 60.0) -> np.ndarray:
    return np.stack(list(pose_sender.clip_positions(WALK, fps=fps, seconds=seconds)))


def received(s: VideoScheduler, n: int, tries: int = 200) -> None:
    """Poll until n packets were accepted or rejected (loopback delivery is near-instant)."""
    for _ in range(tries):
        s.poll()
        if s.received + sum(s.rejected.values()) >= n:
            return
        threading.Event().wait(0.005)
    raise AssertionError(f"only {s.received} accepted + {dict(s.rejected)} rejected of {n} packets")


# ---- every scheduler ----

@pytest.mark.parametrize("name", SCHEDULERS)
def test_each_scheduler_yields_valid_frames(env, name):
    options = {"keyboard": {"script": [(0.5, "left"), (1.0, "faster"), (1.5, "style:run"), (2.5, "stop")]}}.get(name, {})
    s = make_scheduler(name, env, **options)
    rng = np.random.default_rng(0)
    try:
        if name == "video":
            send_now(s.port, walk_positions(1.0))
            received(s, 61)
        s.begin(rng, None, None, align_to=env.qpos.copy())
        lookback, ahead = env.ex.rsis_frames[1] + 1, env.ex.tau + 1
        for _ in range(200):
            for i in (-lookback, -1, 0, 1, ahead):
                check_frame(env, s.frame(i))
            assert isinstance(s.status(), dict) and isinstance(s.clip_id, str)
            s.advance(rng, s.frame(0).qpos.copy())
        assert not s.done
    finally:
        if hasattr(s, "close"):
            s.close()


def test_factory_rejects_unknown_names(env):
    with pytest.raises(ValueError, match="'tv' is not one of dataset, stitch, keyboard, video"):
        make_scheduler("tv", env)


# ---- dataset: deviation reschedule ----

def test_dataset_scheduler_reschedules_on_deviation(env):
    clip = env.scheduler.clip_ids[0]
    rng = np.random.default_rng(0)
    plain = DatasetScheduler(env.ref_model, env._motion, [clip], np.ones(1), env.dt)
    watch = DatasetScheduler(env.ref_model, env._motion, [clip], np.ones(1), env.dt, max_deviation_m=0.5)
    for s in (plain, watch):
        s.begin(rng, clip, 0.0)
    for step in range(30):
        far = watch.frame(1).qpos.copy()
        far[0:2] += [2.0, 0.0]
        assert plain.advance(rng, far) is False
        if watch.advance(rng, far):
            break
    assert step + 1 == watch.deviation_grace_steps and watch.deviation_reschedules == 1
    # realigned under the character, same clip, same clip time
    assert np.linalg.norm(watch.frame(0).qpos[0:2] - far[0:2]) < 1e-9
    assert watch.clip_id == clip and watch.status()["clip_time_s"] == pytest.approx(plain.status()["clip_time_s"])
    # a character on its target is never rescheduled
    assert not any(watch.advance(rng, watch.frame(1).qpos.copy()) for _ in range(30))
    with pytest.raises(ValueError, match="max_deviation_m"):
        DatasetScheduler(env.ref_model, env._motion, [clip], np.ones(1), env.dt, max_deviation_m=-1.0)


def test_dataset_frames_sampled_in_chunks_are_those_of_the_whole_schedule(env):
    """`frame` samples the schedule `CHUNK_ROWS` rows at a time as it reaches them; every frame,
    across chunk borders, past the end and after an aligned reschedule, is bit for bit the frame
    of a schedule sampled whole at `begin`."""
    clips = list(env.scheduler.clip_ids)
    chunked = DatasetScheduler(env.ref_model, env._motion, clips, np.ones(len(clips)) / len(clips), env.dt, lookahead=2)
    whole = DatasetScheduler(env.ref_model, env._motion, clips, np.ones(len(clips)) / len(clips), env.dt, lookahead=2)
    whole.CHUNK_ROWS = 10**9
    rng_a, rng_b = np.random.default_rng(3), np.random.default_rng(3)
    chunked.begin(rng_a, "humanoid3d_walk", 0.2)
    whole.begin(rng_b, "humanoid3d_walk", 0.2)
    assert len(chunked._q) < len(whole._q)  # the walk's rest is longer than a chunk
    aligned = 0
    for _ in range(400):
        for i in (-13, -1, 0, 1, 2, 3):
            a, b = chunked.frame(i), whole.frame(i)
            assert np.array_equal(a.qpos, b.qpos) and np.array_equal(a.qvel, b.qvel)
        pose = whole.frame(1).qpos.copy()
        pose[0:2] += 0.3  # the next clip is placed under a character off its target
        moved = chunked.advance(rng_a, pose)
        assert moved == whole.advance(rng_b, pose)
        aligned += moved
    assert aligned >= 1 and chunked.clip_id == whole.clip_id


@pytest.mark.parametrize("speed", [1.0, 1.5])
def test_dataset_velocities_are_whole_at_the_clips_first_and_last_frames(env, speed):
    """At a clip's first and last frames the target velocity is the difference over two control
    steps inside the clip (one-sided), as inside it (centred); a centred window over the held
    end frame gave half of it (a run's start frame got half its speed)."""
    run = "humanoid3d_run"
    s = DatasetScheduler(env.ref_model, env._motion, [run], np.ones(1), env.dt, speed=speed, at_end="stop")
    s.begin(np.random.default_rng(0), run, 0.0)

    def velocity(i, j):  # (qpos of frame j - qpos of frame i) per second, MuJoCo's tangent space
        v = np.zeros(env.nv)
        mujoco.mj_differentiatePos(env.ref_model, v, (j - i) * env.dt, s.frame(i).qpos, s.frame(j).qpos)
        return v

    np.testing.assert_allclose(s.frame(0).qvel, velocity(0, 2), atol=1e-9)
    assert s.frame(0).qvel[0] > 2.5 * speed  # the run's forward speed (m/s), not half of it
    np.testing.assert_allclose(s.frame(10).qvel, velocity(9, 11), atol=1e-9)
    k = s.last_k  # the last frame the schedule reaches (at or just before the clip's end)
    end_s = s.status()["clip_duration_s"]
    assert s.t0 + k * env.dt * speed <= end_s + 1e-9
    assert s.frame(k).qvel[0] > 0.75 * velocity(k - 2, k)[0] > 1.0


# ---- stitch ----

def stitched(env, transition_s: float, steps: int = 200):
    s = StitchScheduler(env.ref_model, env._motion, env.dt, [(WALK, 0.0, 1.0), "humanoid3d_run", ("humanoid3d_kick", 0.0, 1.0)],
                        transition_s=transition_s)
    rng = np.random.default_rng(0)
    s.begin(rng)
    rows, where = [], []
    for _ in range(steps):
        rows.append(s.frame(0).qpos.copy())
        where.append((s.status()["segment"], s.clip_id))
        s.advance(rng, rows[-1])
    within = np.array([a == b == ("clip", a[1]) for a, b in zip(where[:-1], where[1:])])
    return s, np.array(rows), within


def test_stitch_has_no_jump_across_a_stitch(env, pm):
    s, q, within = stitched(env, 0.3)
    assert s.stitches == 2 and (~within).sum() >= 2 * 18
    joint = pm.joint_angle_change(q[:-1], q[1:]).max(axis=1)
    root = np.linalg.norm(np.diff(q[:, 0:3], axis=0), axis=1)
    # across the stitches no step changes a joint or moves the root more than steps within the clips do
    assert joint[~within].max() <= joint[within].max()
    assert joint[~within].max() < 0.15
    assert root[~within].max() <= root[within].max() + 0.005
    # negative control: without transition frames the stitch is a jump
    _, q0, within0 = stitched(env, 0.0)
    joint0 = pm.joint_angle_change(q0[:-1], q0[1:]).max(axis=1)
    assert joint0[~within0].max() > 2 * joint[within].max()


def test_stitch_queue_while_running_holds_when_dry_and_validates(env):
    rng = np.random.default_rng(0)
    s = StitchScheduler(env.ref_model, env._motion, env.dt, [(WALK, 0.0, 0.3)], transition_s=0.1)
    s.begin(rng)
    for _ in range(40):
        s.advance(rng, s.frame(0).qpos)
    assert s.holding and np.allclose(s.frame(0).qvel, 0.0)
    s.enqueue("humanoid3d_run", 0.0, 0.3)
    assert s.status()["queue"] == ["humanoid3d_run"]
    for _ in range(12):
        s.advance(rng, s.frame(0).qpos)
    assert not s.holding and s.clip_id == "humanoid3d_run"
    with pytest.raises(ValueError, match=r"unknown clip 'no_such_clip'; known clips \(\d+\): humanoid3d_backflip"):
        make_scheduler("stitch", env).enqueue("no_such_clip")
    with pytest.raises(ValueError, match="start 2.0 s and end 1.0 s"):
        s.enqueue(WALK, 2.0, 1.0)
    # the wrong type, not only the wrong value: a clear ValueError naming it
    for bad in (123, None, {"clip": WALK}):
        with pytest.raises(ValueError, match="a stitch item is a clip id or"):
            s.enqueue(bad)
    with pytest.raises(ValueError, match="start x s"):
        s.enqueue((WALK, "x", None))
    with pytest.raises(ValueError, match="stitch clips 5 must be a list"):
        make_scheduler("stitch", env, clips=5)
    # loop=True plays the program again instead of holding
    looped = StitchScheduler(env.ref_model, env._motion, env.dt, [(WALK, 0.0, 0.3)], transition_s=0.1, loop=True)
    looped.begin(rng)
    for _ in range(80):
        looped.advance(rng, looped.frame(0).qpos)
    assert not looped.holding and looped.stitches >= 2


# ---- keyboard ----

def travel_heading(q: np.ndarray) -> float:
    d = q[-1, 0:2] - q[0, 0:2]
    return math.atan2(d[1], d[0])


def test_keyboard_turns_and_speeds_up(env):
    s = KeyboardScheduler(env.ref_model, env._motion, env.dt, style="walk", turn_step_rad=math.radians(30.0),
                          max_turn_rate=math.radians(120.0))
    rng = np.random.default_rng(0)
    s.begin(rng)
    cycle = s._cycle("walk").n

    def run(n: int) -> np.ndarray:
        rows = []
        for _ in range(n):
            rows.append(s.frame(0).qpos.copy())
            s.advance(rng, rows[-1])
        return np.array(rows)

    # whole cycles, so every run starts at the same phase of the walk
    before = run(cycle)
    assert travel_heading(before) == pytest.approx(0.0, abs=math.radians(3))
    s.command("left")
    turning = run(cycle)
    assert s.heading_rad == pytest.approx(math.radians(30.0), abs=1e-9)
    after = run(cycle)
    assert travel_heading(after) == pytest.approx(math.radians(30.0), abs=math.radians(4))
    assert [k for k, _ in s.log] == [cycle]
    # the target root turned too: its heading one cycle apart, at the same phase, differs by the turn
    turn = heading(quat_to_mat(after[0, 3:7])) - heading(quat_to_mat(before[0, 3:7]))
    assert turn == pytest.approx(math.radians(30.0), abs=math.radians(2))
    # 30 degrees at 120 deg/s: done 15 steps after the key
    heading_mid = heading(quat_to_mat(turning[15, 3:7])) - heading(quat_to_mat(before[15, 3:7]))
    assert heading_mid == pytest.approx(math.radians(30.0), abs=math.radians(2))
    speed = np.linalg.norm(after[-1, 0:2] - after[0, 0:2])
    s.command("faster")
    run(cycle)
    faster = run(cycle)
    assert np.linalg.norm(faster[-1, 0:2] - faster[0, 0:2]) == pytest.approx(1.25 * speed, rel=0.03)
    s.command("stop")
    run(cycle)
    stopped = run(cycle)
    assert np.linalg.norm(stopped[-1, 0:2] - stopped[0, 0:2]) < 1e-9


def test_keyboard_styles_come_from_the_library_and_a_take_loops_over_its_closest_span(env, pm):
    """Every Bandai Namco walk, run and dash style is a keyboard style; a take of several strides
    loops over a span of it whose seam is no bigger a jump than its own steps."""
    styles = locomotion_styles()
    assert {"walk", "run", "crawl", "happy_walk", "tired_run", "proud_dash", "elderly_walk"} <= set(styles)
    assert styles["happy_walk"].startswith("humanoid/bandai/dataset-1_walk_happy_")
    s = KeyboardScheduler(env.ref_model, env._motion, env.dt, style="happy_walk")
    take_s = env._motion(styles["happy_walk"]).duration_s
    cycle = s._cycle("happy_walk")
    assert 1.0 < cycle.period_s < take_s * 2 / 3 and cycle.speed_mps > 0.5
    loop = np.concatenate([cycle.q, cycle.q[:1]])  # round the loop and across its seam
    steps = pm.joint_angle_change(loop[:-1], loop[1:]).max(axis=1)
    assert steps[-1] <= 1.2 * steps[:-1].max() and steps.max() < 0.4
    rng = np.random.default_rng(0)
    s.begin(rng)
    rows = []
    for _ in range(2 * cycle.n):
        rows.append(s.frame(0).qpos.copy())
        s.advance(rng, rows[-1])
    assert travel_heading(np.array(rows)) == pytest.approx(0.0, abs=math.radians(5))


def test_keyboard_style_switch_is_smooth_and_keys_are_checked(env, pm):
    s = KeyboardScheduler.from_script(env.ref_model, env._motion, env.dt, [(0.5, "style:run"), (1.0, "style:walk")])
    rng = np.random.default_rng(0)
    s.begin(rng)
    rows = []
    for _ in range(90):
        rows.append(s.frame(0).qpos.copy())
        s.advance(rng, rows[-1])
    assert [k for _, k in s.log] == ["style:run", "style:walk"] and s.style == "walk"
    q = np.array(rows)
    assert pm.joint_angle_change(q[:-1], q[1:]).max() < 0.4
    assert np.linalg.norm(np.diff(q[:, 0:3], axis=0), axis=1).max() < 0.08
    with pytest.raises(ValueError, match="key 'jump' is not one of left, right, faster"):
        s.command("jump")
    with pytest.raises(ValueError, match="style 'moonwalk' is not one of crawl, run, walk"):
        s.command("style:moonwalk")
    with pytest.raises(ValueError, match="seconds must be finite"):
        KeyboardScheduler(env.ref_model, env._motion, env.dt, script=[(-1.0, "left")])


# ---- video ----

def test_video_replays_a_clip_sent_over_udp(env):
    """A walk sent in real time by `send_clip` (a thread) comes back through the IK: the body
    positions of the frames served while it arrives match the clip's."""
    model = env.ref_model
    motion = env._motion(WALK)
    rng = np.random.default_rng(0)
    with VideoScheduler(model, env.dt, delay_s=0.1) as s:
        s.begin(rng)
        sender = threading.Thread(target=pose_sender.send_clip, args=(WALK,),
                                  kwargs={"port": s.port, "fps": 60.0, "seconds": 1.0}, daemon=True)
        sender.start()
        served = []
        tick = threading.Event()
        for _ in range(150):
            if not sender.is_alive() and s.received >= 61:
                break
            s.advance(rng, model.qpos0)
            if s.received >= 10 and not s.late:
                served.append((s.status()["clip_time_s"], s.frame(0).qpos.copy()))
            tick.wait(env.dt)
        sender.join(5.0)
        s.poll()
        assert s.received == 61 and not s.rejected
        assert len(served) >= 20
        errors = [np.linalg.norm(body_positions(model, q) - body_positions(model, motion.qpos(t)), axis=1).mean() for t, q in served]
        assert np.mean(errors) < 0.05
        # and the whole buffer, sampled anywhere
        ts = np.linspace(0.0, 1.0, 25)
        errors = [np.linalg.norm(body_positions(model, s.sample(t).qpos) - body_positions(model, motion.qpos(t)), axis=1).mean()
                  for t in ts]
        assert np.mean(errors) < 0.05
        # velocities are finite differences of the buffer: the root moves forward at the walk's speed
        assert s.sample(0.5).qvel[0] == pytest.approx(0.98, abs=0.35)


def test_video_rejects_bad_packets_and_keeps_serving(env):
    model = env.ref_model
    good = walk_positions(0.2)
    j = len(good[0])
    rng = np.random.default_rng(0)
    with VideoScheduler(model, env.dt) as s:
        send_now(s.port, good[:5])
        received(s, 5)
        s.begin(rng)
        last = s.sample(s.times[-1]).qpos.copy()
        packet = pose_packet.encode(5, 5 / 60, good[5])
        nan = good[5].copy()
        nan[3, 1] = np.nan
        header = struct.Struct("<4sBBHId")
        bad = {
            "short": b"\x00\x01garbage",
            "magic": b"JUNK" + packet[4:],
            "version": packet[:4] + bytes([9]) + packet[5:],
            "joint_count": pose_packet.encode(5, 5 / 60, good[5][:-1]),
            "size": packet[:-3],
            "oversized": packet + bytes(4000),
            "non_finite": pose_packet.encode(5, 5 / 60, nan),
            "out_of_range": pose_packet.encode(5, 5 / 60, good[5] + 1e5),
            "out_of_order": pose_packet.encode(2, 2 / 60, good[2]),
        }
        assert header.size == 20 and len(packet) == 20 + 12 * j == 200
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            for data in bad.values():
                sock.sendto(data, ("127.0.0.1", s.port))
        received(s, 5 + len(bad))
        assert dict(s.rejected) == {reason: 1 for reason in bad}
        assert s.received == 5 and s.last_error.startswith("out_of_order")
        for _ in range(20):
            s.advance(rng, model.qpos0)
            check_frame(env, s.frame(1))
        np.testing.assert_allclose(s.frame(0).qpos, last, atol=1e-12)  # the last good frame, held
        assert s.late and np.allclose(s.frame(0).qvel, 0.0)
        # a good packet after all that is taken
        send_now(s.port, good[5:6], t0=5 / 60)
        received(s, 6 + len(bad))
        assert s.received == 6
    assert s.closed and s.poll() == 0


def test_send_poses_cli_and_keypoint_files(env, tmp_path):
    from learner.cli import COMMANDS

    assert COMMANDS["send-poses"][0] == "learner.live.pose_sender"
    with VideoScheduler(env.ref_model, env.dt) as s:
        assert pose_sender.main([WALK, "--port", str(s.port), "--fps", "60", "--seconds", "0.1"]) == 0
        received(s, 7)
        assert s.received == 7
        path = tmp_path / "keypoints.npz"
        np.savez(path, positions=walk_positions(0.1), fps=np.array(120.0))
        assert pose_sender.main([str(path), "--port", str(s.port)]) == 0
        received(s, 7 + 7)
        assert s.received == 7 + 7 and s.restarts == 1  # the file's stream starts over (frame index 0)
    assert pose_sender.main(["no_such_clip", "--port", "9"]) == 2


# ---- the executor ----

@pytest.mark.parametrize("name", SCHEDULERS)
def test_executor_runs_with_each_scheduler(env, name):
    s = make_scheduler(name, env)
    try:
        if name == "video":
            send_now(s.port, walk_positions(1.0))
            received(s, 61)
        env.use_scheduler(s)
        obs, info = env.reset(0, env.space.default_array)
        assert env.scheduler is s and info["clip_id"] == s.clip_id
        for _ in range(50):
            obs, reward, terminated, truncated, info = env.step(np.zeros(env.act_dim))
            assert np.all(np.isfinite(obs)) and math.isfinite(reward) and not info["diverged"]
            if terminated or truncated:
                env.reset(None, env.space.default_array)
    finally:
        if hasattr(s, "close"):
            s.close()
        env.use_scheduler(make_scheduler("dataset", env))
    with pytest.raises(TypeError, match="not a Scheduler"):
        env.use_scheduler(object())


def test_a_reset_resumes_stitch_keyboard_and_video_and_redraws_the_dataset(env):
    """`ExecutorEnv.reset`: the first reset after `use_scheduler` begins a scheduler; later
    ones resume stitch (and keyboard, video: `restarts_on_reset` False) with the character on
    the current target frame, while the dataset scheduler begins a new draw at each one."""
    assert DatasetScheduler.restarts_on_reset and not any(
        c.restarts_on_reset for c in (StitchScheduler, KeyboardScheduler, VideoScheduler))
    s = make_scheduler("stitch", env, clips=(WALK, "humanoid3d_run"))
    try:
        env.use_scheduler(s)
        _, info = env.reset(0, env.space.default_array)
        assert not info["resumed"] and s.status()["clip_time_s"] == pytest.approx(0.0)
        for _ in range(30):
            env.step(np.zeros(env.act_dim))
        before = s.status()
        target = s.frame(0).qpos.copy()
        _, info = env.reset(1, env.space.default_array, clip_id=WALK)  # a clip id does not rewind a resumed queue
        assert info["resumed"] and info["rsis_offset"] == 0 and env.grace == 0
        assert s.status()["clip_time_s"] == pytest.approx(before["clip_time_s"]) == pytest.approx(30 * env.dt)
        q = env.qpos  # on the frame (lifted out of the floor at most)
        np.testing.assert_allclose(np.r_[q[0:2], q[3:]], np.r_[target[0:2], target[3:]], atol=1e-9)
        assert q[2] >= target[2] - 1e-9
        _, info = env.reset(2, env.space.default_array, restart=True)
        assert not info["resumed"] and s.status()["clip_time_s"] == pytest.approx(0.0)
    finally:
        env.use_scheduler(make_scheduler("dataset", env))
    draws = set()
    for seed in range(4):
        _, info = env.reset(seed, env.space.default_array)
        assert not info["resumed"]
        draws.add((info["clip_id"], round(env.scheduler.t0, 6)))
    assert len(draws) > 1
