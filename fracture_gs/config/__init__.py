"""Scene configuration: YAML schema, validation and the typed, resolved ``SceneConfig``. Its settings
types (``Domain``, ``ContactSettings``, the boundaries) are also the solver's."""
from fracture_gs.config.scene import (Boundary, BoxBoundary, ContactSettings, Domain, GroundBoundary, MaterialConfig,
                                      ObjectConfig, PrimitiveConfig, SceneConfig, SceneError, TransformConfig,
                                      load_scene, parse_scene, read_yaml)

__all__ = ["Boundary", "BoxBoundary", "ContactSettings", "Domain", "GroundBoundary", "MaterialConfig",
           "ObjectConfig", "PrimitiveConfig", "SceneConfig", "SceneError", "TransformConfig", "load_scene",
           "parse_scene", "read_yaml"]
