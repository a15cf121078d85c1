"""Characters from shape parameters (Won & Lee 2019; METHOD.md A): C = F(B, b).

    from common.characters import load_character, list_presets, morph, ShapeError, Character
    ch = load_character("lower_biped", shape={"left_leg": 1.1}, parameterization="left_right_leg")
    data = ch.make_data()                  # MjData at the solved standing pose
    ch2, data = morph(ch, {"left_leg": 0.95}, data)   # shape change during simulation

Presets: humanoid (DeepMimic), biped (MASS 19 segments), lower_biped, quadruped, fish, manta;
any MJCF with a free root as "mjcf:/path/to/file.xml". See character.py for the fields.
"""

from common.characters.character import (DEFAULT_TIMESTEP_S, Character, CharacterFactory, base_character, list_presets,
                                        load_character)
from common.characters.errors import ShapeError
from common.characters.morph import morph
from common.characters.shape_space import BodyPart, ShapeParam, ShapeSpace

__all__ = [
    "Character", "CharacterFactory", "base_character", "load_character", "list_presets", "morph", "ShapeError", "ShapeSpace", "ShapeParam",
    "BodyPart", "DEFAULT_TIMESTEP_S",
]
