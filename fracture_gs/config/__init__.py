"""Scene configuration: YAML schema, validation and the typed, resolved ``SceneConfig``."""
from fracture_gs.config.scene import (BoundaryConfig, BoxConfig, ContactConfig, DomainConfig,
                                      GroundConfig, MaterialConfig, ObjectConfig,
                                      PrimitiveConfig, SceneConfig, SceneError, TransformConfig,
                                      load_scene, parse_scene, read_yaml)

__all__ = ["BoundaryConfig", "BoxConfig", "ContactConfig", "DomainConfig", "GroundConfig",
           "MaterialConfig", "ObjectConfig", "PrimitiveConfig", "SceneConfig", "SceneError",
           "TransformConfig", "load_scene", "parse_scene", "read_yaml"]
