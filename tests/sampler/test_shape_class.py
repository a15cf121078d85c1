"""Shape and motion class drawn together (`--sampler.shape-by-class`, issue 55 item 2): Vm over
(shape, class), a buffer per class, the balancer's class frequencies, state, refused reports,
the class map, and draws exactly as before with the switch off."""

from __future__ import annotations

import dataclasses
import hashlib
import json

import numpy as np
import pytest
import torch

from common import wire
from common.motion.balancer import load_clip_labels
from common.params import ParamSpace
from sampler import state_file
from sampler.actor import start_in_thread
from sampler.client import SamplerClient
from sampler.config import SamplerConfig
from sampler.plot import main as plot_main, plot_state
from sampler.service import _check_restored
from sampler.shape_sampler import ShapeSampler

SPACE = ParamSpace(names=("leg", "arm"), low=(0.5, 2.0), high=(2.0, 3.0))
CLIPS = [("walk1", "root/loco/walk"), ("walk2", "root/loco/walk/happy"), ("jump1", "root/loco/jump"),
         ("flip1", "root/acro/flip/back"), ("flip2", "root/acro/flip/front"), ("roll1", "root/acro/roll")]
"""Classes at depth 2: root/acro/flip (flip1, flip2), root/acro/roll, root/loco/jump, root/loco/walk (walk1, walk2)."""
CFG = SamplerConfig(k=5.0, p_mcmc=2, n_mcmc=200, n_chains=16, burn_in=40, thin=3, vm_fit_steps=60,
                    vm_minibatch=128, probe_points=128, seed=5, shape_by_class=True)
WALK, FLIP = "root/loco/walk", "root/acro/flip"


def values_of(sampler: ShapeSampler, params: np.ndarray, clips: list[str]) -> np.ndarray:
    """Walks are hard on long legs, flips on short legs, the other classes do not care (and
    walks are the hardest class over the box)."""
    cls = np.array([sampler.class_names[sampler.class_of_clip[c]] for c in clips])
    leg = params[:, 0] - 0.5  # 0 .. 1.5
    return np.select([cls == WALK, cls == FLIP], [30.0 + 40.0 * (1.5 - leg), 40.0 + 40.0 * leg], 90.0)


def train(sampler: ShapeSampler, iterations: range) -> dict[str, float]:
    stats = {}
    for it in iterations:
        params, clips = sampler.draw(600)
        sampler.report(params, values_of(sampler, params, clips), pair_clips=clips)
        stats = sampler.tick(it)
    return stats


@pytest.fixture(scope="module")
def trained() -> tuple[ShapeSampler, dict[str, float]]:
    s = ShapeSampler(CFG, SPACE, CLIPS)
    return s, train(s, range(1, 9))


def test_vm_learns_the_class_dependent_value_and_each_buffer_goes_where_its_class_is_hard(trained):
    s, stats = trained
    assert s.class_names == ("root/acro/flip", "root/acro/roll", "root/loco/jump", "root/loco/walk")
    walk, flip = s.class_names.index(WALK), s.class_names.index(FLIP)
    short, long_ = np.array([[0.6, 2.5]]), np.array([[1.9, 2.5]])
    assert s.vm(long_, walk)[0] < s.vm(short, walk)[0] - 30  # walks: long legs hard
    assert s.vm(short, flip)[0] < s.vm(long_, flip)[0] - 30  # flips: short legs hard
    n = s.per_class
    legs = {name: s.buffer[c * n:(c + 1) * n, 0].mean() for c, name in enumerate(s.class_names)}
    assert legs[WALK] > 1.45 and legs[FLIP] < 1.05  # uniform: 1.25
    assert abs(legs["root/loco/jump"] - 1.25) < 0.12  # a flat class stays spread out
    # its metrics: Vm over each buffer, Vbar_c, and the class of lowest value
    assert stats[f"vm/class/{WALK}/min"] < 40 < stats[f"vm/class/{WALK}/max"] < 95  # Vm(., walk) is 30 .. 90
    assert stats[f"vm/class/{FLIP}/vbar"] == pytest.approx(s.vm.vbar_c[flip])
    assert stats[f"vm/class/root/loco/jump/vbar"] == pytest.approx(90, abs=5)
    assert stats[f"vm/lowest/{WALK}"] == stats["vm/lowest_vbar"] == pytest.approx(s.vm.vbar_c[walk])
    assert [k for k in stats if k.startswith("vm/lowest/")] == [f"vm/lowest/{WALK}"]
    assert stats["buffer/generation"] == 4 and 0 < stats["mcmc/acceptance"] < 1


def test_classes_are_drawn_as_the_balancer_says():
    s = ShapeSampler(CFG, SPACE, CLIPS)
    train(s, range(1, 3))  # buffers concentrated: the classes must not follow them
    clips = [c for _ in range(20) for c in s.draw(1000)[1]]
    p = s.balancer.draw_probabilities
    for c, name in enumerate(s.class_names):
        want = sum(p[i] for i, cid in enumerate(s.clips.clip_ids) if s.class_of_clip[cid] == c)
        got = np.mean([s.class_of_clip[cid] == c for cid in clips])
        assert got == pytest.approx(want, abs=4 * np.sqrt(want * (1 - want) / len(clips)))
    assert {s.class_names[s.class_of_clip[c]] for c in clips} == set(s.class_names)  # every class in play


def test_each_draw_takes_its_shape_from_its_class_buffer_in_a_shuffled_pass():
    s = ShapeSampler(dataclasses.replace(CFG, n_mcmc=30), SPACE, CLIPS)
    params, clips = s.draw(3000)
    n = s.per_class
    for c in range(len(s.class_names)):
        mine = params[[s.class_of_clip[cid] == c for cid in clips]]
        rows = s.buffer[c * n:(c + 1) * n]
        assert len(mine) > n and all((np.abs(rows - p).sum(axis=1) < 1e-12).any() for p in mine)
        first = mine[:n]  # a full pass: every row once
        np.testing.assert_array_equal(np.sort(first, axis=0), np.sort(rows, axis=0))


def test_state_round_trips_through_the_state_file_and_old_states_load(tmp_path, trained):
    s, _ = trained
    params, clips = s.draw(50)
    s.report(params, values_of(s, params, clips), pair_clips=clips)  # pending pairs with their classes
    state_file.save(tmp_path, s.state_dict())
    loaded = state_file.load(tmp_path)
    assert loaded["meta"]["version"] == 2 and loaded["meta"]["classes"] == list(s.class_names)
    twin = ShapeSampler(CFG, SPACE, CLIPS)
    twin.load_state_dict(loaded)
    _check_restored(twin)
    assert twin.pending_pairs == 50
    np.testing.assert_array_equal(np.concatenate(twin._pending_classes), np.concatenate(s._pending_classes))
    a, b = s.draw(500), twin.draw(500)
    np.testing.assert_array_equal(a[0], b[0])
    assert a[1] == b[1]
    timeless = lambda st: {k: v for k, v in st.items() if not k.endswith("_s")}  # noqa: E731
    assert timeless(s.tick(20)) == timeless(twin.tick(20))
    # A version 1 state (over shapes alone) loads: every class starts from the old Vm, the buffers are
    # refilled per class, and its pending pairs, which name no class, are dropped and counted.
    old = ShapeSampler(dataclasses.replace(CFG, shape_by_class=False), SPACE, CLIPS)
    for it in (1, 2):
        p, _ = old.draw(300)
        old.report(p, 40.0 + 40.0 * (p[:, 0] - 0.5))
        old.tick(it)
    old.report(*old.draw(7)[:1], np.ones(7))
    v1 = old.state_dict()
    v1["meta"] = {k: v for k, v in v1["meta"].items() if k not in ("classes", "class_cursors", "class_acceptance")}
    v1["meta"]["version"] = 1
    v1["meta"]["vm"] = {k: v for k, v in v1["meta"]["vm"].items() if k not in ("classes", "vbar_c", "probe_std_c", "class_seen")}
    new = ShapeSampler(CFG, SPACE, CLIPS)
    new.load_state_dict(v1)
    _check_restored(new)
    grid = SPACE.uniform(np.random.default_rng(0), 64)
    for c in range(len(new.class_names)):
        np.testing.assert_allclose(new.vm(grid, c), old.vm(grid), rtol=1e-5)
        assert new.vm.vbar_c[c] == old.vm.vbar
    assert new.pending_pairs == 0 and new.pairs_trimmed == 7 and new.pairs_taken == old.pairs_taken
    assert len(new.buffer) == CFG.n_mcmc * len(new.class_names) and new.generation == old.generation + 1
    # and back: a state over classes into a sampler over shapes alone (the switch turned off)
    off = ShapeSampler(dataclasses.replace(CFG, shape_by_class=False), SPACE, CLIPS)
    off.load_state_dict(s.state_dict())
    _check_restored(off)
    average_class = np.concatenate([s.vm.normalize(grid), np.full((len(grid), len(s.class_names)), 1 / len(s.class_names))], 1)
    with torch.no_grad():
        at_average = s.vm.mu + s.vm.sigma * s.vm.net(torch.as_tensor(average_class, dtype=torch.float32)).squeeze(-1).double().numpy()
    np.testing.assert_allclose(off.vm(grid), at_average, rtol=1e-4)  # Vm of the average class
    assert len(off.buffer) == CFG.n_mcmc and off.pending_pairs == s.pending_pairs


def test_bad_value_reports_are_refused_and_counted():
    svc, thread, stop = start_in_thread(dataclasses.replace(CFG, n_mcmc=20, burn_in=4), SPACE, CLIPS)
    plain_svc, plain_thread, plain_stop = start_in_thread(dataclasses.replace(CFG, shape_by_class=False), SPACE, CLIPS)
    client, plain = SamplerClient(svc.endpoint, timeout_s=5.0), SamplerClient(plain_svc.endpoint, timeout_s=5.0)
    try:
        d = client.draw(4)
        values = np.full(4, 50.0)
        with pytest.raises(wire.WireError, match=r"pair_clips\[2\] = 'moonwalk' is not a clip this sampler draws"):
            client.report(d.params, values, pair_clips=[d.clip_ids[0], d.clip_ids[1], "moonwalk", d.clip_ids[3]])
        with pytest.raises(wire.WireError, match="0 pair clip ids for 4 pairs"):
            client.report(d.params, values)
        with pytest.raises(wire.WireError, match="m = 4 here but 3 elsewhere"):  # one clip per pair, on the wire
            client.report(d.params, values, pair_clips=d.clip_ids[:3])
        with pytest.raises(wire.WireError, match="NaN or Inf"):
            client.report(d.params, np.array([50.0, np.nan, 50.0, 50.0]), pair_clips=d.clip_ids)
        with pytest.raises(wire.WireError, match=r"shape-by-class off\); send none"):
            plain.report(d.params, values, pair_clips=d.clip_ids)
        stats = client.stats()
        assert stats["requests/rejected/invalid"] == 2 and stats["requests/rejected/bad_shape"] == 1
        assert stats["requests/rejected/nonfinite"] == 1 and stats["vm/pairs_taken"] == 0
        assert plain.stats()["requests/rejected/invalid"] == 1
        client.report(d.params, values, pair_clips=d.clip_ids)  # the good one goes through
        assert client.tick(1)["vm/pairs_seen"] == 4
    finally:
        client.close()
        plain.close()
        for st, th in ((stop, thread), (plain_stop, plain_thread)):
            st.set()
            th.join(timeout=5)


def test_the_class_map_has_a_panel_per_class(tmp_path, trained):
    s, _ = trained
    out = plot_state(s.state_dict(), SPACE, tmp_path / "vm_classes.png", params=("arm", "leg"), resolution=16)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    state_file.save(tmp_path / "sampler", s.state_dict())
    assert plot_main([str(tmp_path / "sampler"), str(tmp_path / "cmd.png")]) == 0
    assert (tmp_path / "cmd.png").stat().st_size > 5000


def test_the_switch_needs_clips_and_a_sane_depth():
    with pytest.raises(ValueError, match="needs a task with clips"):
        ShapeSampler(CFG, SPACE)
    with pytest.raises(ValueError, match="--sampler.class-depth = 0"):
        dataclasses.replace(CFG, class_depth=0)
    shallow = ShapeSampler(dataclasses.replace(CFG, class_depth=1), SPACE, CLIPS)
    assert shallow.class_names == ("root/acro", "root/loco")


def test_with_the_switch_off_draws_are_what_they_were():
    """The digest of a k = 0 run's draws (clips, buffer, refills; numpy alone, no float Vm in the
    way) as the code before `shape_by_class` gave it (commit 6b708ea); the k > 0 paths are held
    by the unchanged tests of test_shape_sampler.py."""
    cfg = SamplerConfig(k=0.0, p_mcmc=2, n_mcmc=64, n_chains=8, burn_in=10, thin=2, vm_fit_steps=8, vm_minibatch=32,
                        probe_points=32, seed=3)
    s = ShapeSampler(cfg, ParamSpace(names=("leg", "arm"), low=(0.5, 0.5), high=(2.0, 1.5)), load_clip_labels())
    h = hashlib.sha256()
    for it in range(1, 6):
        p, c = s.draw(100)
        h.update(p.tobytes())
        h.update(json.dumps(c).encode())
        s.report(p, 40.0 + 40.0 * (p[:, 0] - 0.5))
        s.tick(it)
    assert h.hexdigest()[:16] == "e35ce907a4c17dae"
    assert "classes" not in s.state_dict()["arrays"] and not any(k.startswith("vm/class/") for k in s.stats())
