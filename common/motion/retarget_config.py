"""`RetargetConfig`: the thresholds of retargeting a clip onto a body (`retarget.py`), on their
own so that the retargeting and the leg solve it drives can both read them. The shape tasks
nest one (`ImitateConfig.retarget`, flags `--task.imitate.retarget.<field>`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from common.config_limits import Limit, above, at_least, between, check_limits, flag, validated
from common.motion.root_height import ROOT_HEIGHT_RULES


@dataclass(frozen=True)
@validated
class RetargetConfig:
    """Thresholds of the retargeting (metres, m/s)."""

    contact_height_m: float = 0.04
    """A foot is in contact on the base character when its lowest point is this close to the clip's floor..."""
    contact_speed_m_s: float = 0.8
    """...and its body moves horizontally slower than this."""
    ik_tolerance_m: float = 0.005
    """Penetrations deeper than this are removed by the leg pose solve."""
    ik_iterations: int = 25
    """Gauss-Newton steps per frame and foot (at most; stops when the foot is there)."""
    ik_orientation_weight_m: float = 0.2
    """Weight (m/rad) of keeping the foot's orientation against reaching its height."""
    ik_damping: float = 1e-3
    """Levenberg damping of the leg solve (m^2)."""
    root_speed_m_s: float = 0.5
    """"contact_smooth" only: the fastest the root height may change (m/s) where the contact set
    switches (`root_height.lower_envelope`)."""
    ramp_s: float = 0.1
    """`body_clearance_m`: seconds over which the root rises before, and settles after, a lift."""
    body_clearance_m: float = 0.0
    """Lift the root where the reference brings a body whose floor contact is a fall closer to
    the floor than this, ramped over `ramp_s` on each side (`clearance_lift`); 0: off. A foot
    floats by the lift on those frames."""
    clearance_shins_may_touch: bool = False
    """`body_clearance_m`: the segment above each foot may touch the floor (the quadruped's task rule)."""
    root_height: str = "contact_set"
    """How the per-frame root offset is chosen (`root_offsets`): "contact_set" puts the highest
    foot of each frame's contact set on the floor; "foot_tracks" the highest of every foot's
    in-contact height, interpolated through that foot's swing (continuous across contact-set
    changes: no root drop when a shorter leg's pair takes over), and the leg solve then shortens
    each longer leg by its track's depth below the floor on every frame (`foot_goals`)."""

    FLAG_PREFIX: ClassVar[str] = "task.imitate.retarget"
    LIMITS: ClassVar[dict[str, Limit]] = {
        "contact_height_m": above(0), "contact_speed_m_s": above(0), "ik_tolerance_m": above(0),
        "ik_iterations": at_least(1), "ik_orientation_weight_m": at_least(0, False), "ik_damping": at_least(0, False),
        "root_speed_m_s": above(0), "ramp_s": at_least(0, False), "body_clearance_m": between(0, 0.1),
    }
    """Allowed values of the numeric fields (`common.config_limits`)."""

    def validate(self) -> None:
        """ValueError naming the first value outside what is allowed."""
        check_limits(self)
        if self.root_height not in ROOT_HEIGHT_RULES:
            raise ValueError(f"{flag(self.FLAG_PREFIX, 'root_height')} = {self.root_height!r}: "
                             f"give {', '.join(ROOT_HEIGHT_RULES)}")
