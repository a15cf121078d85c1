"""The motion library (issue 4): canonical clips, importers, kinematics, retargeting to any
body shape, procedural gaits, the dataset manifest and its UniCon split.

    from common.motion import MotionLibrary
    lib = MotionLibrary()                          # clips of common/data/clips.json
    ref = lib.play("humanoid3d_walk", character)   # a CharacterMotion on this shape
    s = ref.state(t)   # s.qpos (nq,), s.qvel (nv,), s.end_effectors (E, 3), s.com, s.com_vel
    ref.qpos(t + 0.5)  # reference posture ahead (Won & Lee's sensory state)

    clips_for("humanoid")  # [(clip_id, label)] of the clips that play on the humanoid as-is

Modules: clip (format), quat, kinematics, import_deepmimic, bvh + import_bvh, cross_skeleton (a
BVH of another skeleton onto the DeepMimic humanoid: rest-pose correction, feet planted on a
drifting floor), qpos_map (clip -> a model's qpos), reference (CharacterMotion), retarget (on
root_height: where the feet are, the root-height rules; leg_solve: the leg pose solve), procedural, manifest, check, view, cli,
balancer (UniCon's class-tree clip probabilities) and clip_manager (which clip and start time each
environment plays: every clip draw goes through a `ClipManager`).
"""

from common.motion.clip import Clip, load_clip  # noqa: E402
from common.motion.errors import ClipError  # noqa: E402
from common.motion.cross_skeleton import retarget_bvh  # noqa: E402
from common.motion.library import MotionLibrary, clips_for, import_source  # noqa: E402
from common.motion.manifest import Manifest, Split, load_manifest, unicon_split  # noqa: E402
from common.motion.reference import CharacterMotion, ReferenceState  # noqa: E402
from common.motion.retarget import RetargetConfig, play_on  # noqa: E402

__all__ = [
    "CharacterMotion", "Clip", "ClipError", "Manifest", "MotionLibrary", "ReferenceState", "RetargetConfig", "Split",
    "clips_for", "import_source", "load_clip", "load_manifest", "play_on", "retarget_bvh", "unicon_split",
]
