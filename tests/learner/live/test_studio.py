"""`morphmimic studio`: a real viser server on 127.0.0.1 (an ephemeral port) running the shipped
lower_biped, seen by headless Chromium over the DevTools protocol; the page's controls driven
through the same callbacks and command queue the browser's events use. One studio serves the whole
module and stops at its end (each test also bounds its own waits)."""

from __future__ import annotations

import time

import numpy as np
import pytest

from learner.live import studio as studio_mod
from learner.live.studio import Studio
from learner.live.chromium import Chromium, character_pixels, find_chromium

BIPED = "lower_biped"


@pytest.fixture(scope="module")
def studio():
    st = Studio(BIPED, host="127.0.0.1", port=0, idle_unwatched=False).start()  # NOTE: the tests step it without a page
    try:
        yield st
    finally:
        st.stop()
    assert not st.core.running


def wait_for(predicate, timeout_s: float, every_s: float = 0.1):
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        value = predicate()
        if value:
            return value
        time.sleep(every_s)
    return predicate()


def standing_start(session) -> None:
    """A new, uncounted episode: the clip's first pose, upright. The loop walks the body between
    tests and it may lie on the floor when paused; lying, a morph of global_z barely changes the
    vertical extent (CI once measured 0.32 m short against 0.40 m base)."""
    session.reset(cause=None)


def screenshot_until(browser: Chromium, predicate, timeout_s: float) -> np.ndarray:
    """Screenshots until `predicate(image)` holds (or the time is up): the last one."""
    end = time.monotonic() + timeout_s
    img = browser.screenshot()
    while not predicate(img) and time.monotonic() < end:
        time.sleep(0.3)
        img = browser.screenshot()
    return img


@pytest.mark.skipif(find_chromium() is None, reason="chromium is not installed (apt-get install chromium; .ci/run does)")
def test_the_page_shows_the_character_in_3d(studio) -> None:
    assert studio.url.startswith("http://127.0.0.1:")
    with Chromium(studio.url, 1024, 640) as browser:
        shown = screenshot_until(browser, lambda img: character_pixels(img) > 400, studio_mod.SCREENSHOT_TIMEOUT_S)
        assert character_pixels(shown) > 400, "no character in the page's 3-D view"
        assert shown.std() > 10.0  # not a blank page
        assert len(studio.server.get_clients()) == 1
        studio.scene.visible = False  # the same page without the character
        try:
            empty = screenshot_until(browser, lambda img: character_pixels(img) < 50, 30.0)
        finally:
            studio.scene.visible = True
        assert character_pixels(empty) < 50
        h, w = shown.shape[:2]
        canvas = (slice(int(h * 0.3), h - 70), slice(80, w - 420))
        diff = np.abs(shown[canvas].astype(int) - empty[canvas].astype(int)).max(axis=-1)
        assert (diff > 30).sum() > 300  # the character's pixels differ from the empty floor's
        errors = studio.core.errors
        # the arrow keys are the keyboard scheduler's: on a shape controller that is refused, counted, shown
        for kind in ("keyDown", "keyUp"):
            browser.call("Input.dispatchKeyEvent", type=kind, key="ArrowLeft", code="ArrowLeft", windowsVirtualKeyCode=37)
        assert wait_for(lambda: studio.core.errors == errors + 1, 10.0), "the arrow key did not reach the studio"
        assert "steer: schedulers drive the executor" in studio.core.message


def test_a_shape_slider_changes_the_measured_height(studio) -> None:
    core, gui = studio.core, studio.gui
    height = lambda: core.query(lambda s: s.body_height_m())  # noqa: E731 - read on the loop thread
    lo, hi = core.session.shape_box
    i = core.session.shape_names.index("global_z")
    slider = gui._shape_sliders["global_z"]
    errors = core.errors
    assert (slider.min, slider.max) == pytest.approx((lo[i], hi[i]))
    core.set_paused(True)  # NOTE: the same pose before and after, so only the morph changes the height
    assert wait_for(lambda: core.paused, 5.0)
    try:
        core.query(standing_start)
        before = height()
        rebuilds = studio.scene.rebuilds
        slider.value = float(hi[i])  # what dragging it does: its on_update callback queues the morph
        assert wait_for(lambda: core.session.params[i] == pytest.approx(hi[i]), 5.0)
        after = height()
        assert after > before + 0.1
        assert wait_for(lambda: studio.scene.rebuilds > rebuilds, 5.0)  # the 3-D view follows the new model
    finally:
        core.set_paused(False)
    steps = core.loop_steps
    assert wait_for(lambda: core.loop_steps > steps + 5, 5.0)  # and the morphed body walks on
    assert core.session.params[i] == pytest.approx(hi[i]) and core.errors == errors


def test_a_body_preset_morphs_to_its_shape(studio) -> None:
    core, gui = studio.core, studio.gui
    assert {"base", "tall", "short", "wide"} <= set(gui.body_preset.options)
    i = core.session.shape_names.index("global_z")
    errors = core.errors
    core.set_paused(True)  # NOTE: one pose throughout, so only the morphs change the height
    assert wait_for(lambda: core.paused, 5.0)
    try:
        core.query(standing_start)
        gui.body_preset.value = "short"  # what picking it in the page does
        assert wait_for(lambda: core.session.params[i] == pytest.approx(0.6), 5.0)
        short = core.query(lambda s: s.body_height_m())
        gui.body_preset.value = "base"
        assert wait_for(lambda: core.session.params[i] == pytest.approx(1.0), 5.0)
        assert np.allclose(core.session.params[: core.session.n_shape], 1.0)
        assert core.query(lambda s: s.body_height_m()) > short + 0.1 and core.errors == errors
    finally:
        core.set_paused(False)


def test_bad_input_shows_an_error_counts_it_and_the_loop_keeps_stepping(studio) -> None:
    core, gui = studio.core, studio.gui
    errors = core.errors
    core.set_shape({"global_z": 9.0})  # out of the slider's range (typed, or sent by a script)
    assert wait_for(lambda: core.errors == errors + 1, 5.0)
    gui.refresh()
    assert "global_z = 9.0 is outside [0.5, 1.5]" in gui.error_line.content and "error" in gui.error_line.content
    assert f"errors {errors + 1}" in gui.status.content
    gui.clip.value = "nope"  # an unknown clip, through the dropdown's callback
    assert wait_for(lambda: core.errors == errors + 2, 5.0)
    assert "clip 'nope' cannot play with this checkpoint" in core.snapshot()["message"]
    gui.shape_text.value = "global_z=abc"
    gui.shape_apply.value = True  # a click
    assert wait_for(lambda: core.errors == errors + 3, 5.0)
    gui.refresh()
    assert "'global_z=abc' is not NAME=VALUE" in gui.error_line.content
    steps = core.loop_steps
    assert wait_for(lambda: core.loop_steps > steps + 10, 5.0), "the simulation stopped after bad input"
    assert core.running and not core.paused
    assert core.session.params[core.session.shape_names.index("global_z")] <= 1.5


def test_cli_help_and_a_bad_checkpoint(capsys) -> None:
    with pytest.raises(SystemExit) as exit_info:
        studio_mod.main(["--help"])
    assert exit_info.value.code == 0 and "--seconds" in capsys.readouterr().out
    assert studio_mod.main(["--checkpoint", "no/such/checkpoint", "--port", "0", "--seconds", "1"]) == 2
    assert "morphmimic studio:" in capsys.readouterr().err


def test_an_unwatched_studio_idles_and_names_the_checkpoint_as_typed() -> None:
    """No page connected: the loop does not step (CPU idle; measured 29% of a core before, 0.1%
    after); the status names the checkpoint as typed, not its run's name (lb6-shank)."""
    st = Studio("lower_biped-20M", host="127.0.0.1", port=0).start()
    try:
        assert wait_for(lambda: st.core.idle, 5.0)
        steps = st.core.loop_steps
        time.sleep(1.0)
        assert st.core.loop_steps == steps and st.core.running
        snap = st.core.snapshot()
        assert snap["name"] == "lower_biped-20M" and snap["run_name"] == "lb6-shank" and st.core.message == "loaded lower_biped-20M"
        assert studio_mod.status_markdown(snap).startswith("**lower_biped-20M**")
        watching = [True]
        st.core.watched = lambda: bool(watching)  # a page connects
        assert wait_for(lambda: st.core.loop_steps > steps + 10, 5.0) and not st.core.idle
    finally:
        st.stop()


def test_the_executor_loads_from_the_dropdown_and_is_steered(studio) -> None:
    """Last in the module: it swaps the shared studio's session for the executor's."""
    core, gui = studio.core, studio.gui
    generation, errors = core.generation, core.errors
    gui.checkpoint.value = "executor"  # loads in its own thread; the biped keeps walking meanwhile
    assert wait_for(lambda: core.generation == generation + 1, 30.0), core.message
    assert core.session.kind == "executor" and core.errors == errors
    assert wait_for(lambda: core.message == "loaded executor", 5.0), core.message  # said just after the swap
    assert core.snapshot()["name"] == "executor"  # as picked
    gui.refresh()
    assert all(slider.disabled for slider in gui._shape_sliders.values()) and "cannot change" in gui.body_note.content
    assert not gui.scheduler.disabled and "executor" in gui.status.content
    assert wait_for(lambda: studio.scene.model is core.session.env.model, 5.0)  # the 3-D view shows the humanoid
    core.set_shape({"height": 1.0})
    assert wait_for(lambda: core.errors == errors + 1, 5.0) and "cannot change shape" in core.message
    pytest.importorskip("common.tasks.executor.schedulers.factory", reason="the schedulers are not in this checkout")
    gui.keys.value = "left"  # a click on the keyboard button group: switches to the keyboard scheduler
    assert wait_for(lambda: core.message == "keyboard: left", 5.0), core.message
    assert core.scheduler_name == "keyboard"
    gui.queue_clip.value = "humanoid3d_run"
    gui.queue_button.value = True
    assert wait_for(lambda: core.scheduler_name == "stitch", 5.0), core.message
    gui.throw_button.value = True
    assert wait_for(lambda: core.message.startswith("threw a projectile"), 5.0), core.message
    assert core.errors == errors + 1
    steps = core.loop_steps
    assert wait_for(lambda: core.loop_steps > steps + 10, 5.0)
    core.use_scheduler("video")  # its packets in the status line: a 16-joint sender is rejected by reason
    assert wait_for(lambda: core.scheduler_name == "video", 5.0), core.message
    import socket

    from common.tasks.executor.schedulers import pose_packet
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.sendto(pose_packet.encode(0, 0.0, np.zeros((16, 3))), ("127.0.0.1", core.scheduler.port))
    assert wait_for(lambda: "rejected 1 (joint_count 1)" in (core.snapshot()["video"] or ""), 5.0), core.snapshot()["video"]
    assert "received 0, rejected 1 (joint_count 1)" in studio_mod.status_markdown(core.snapshot())
