"""Scene YAML (docs/scenes.md) → validated, typed :class:`SceneConfig` with every default filled in.

Every key is checked before anything runs: types, ranges, unknown keys (typos), mutually
exclusive keys and referenced files. A problem raises :class:`SceneError`, whose message names
the key path, e.g. ``objects[1].materials[0].nu: 0.5 is not < 0.5``.

Checks that need the objects' particles (every part has a material, the transformed object
lies inside the domain) happen when the particles are built (:mod:`fracture_gs.mpm.scene`);
they raise the same :class:`SceneError`, still before the simulation starts.

Conventions:

* ``transform`` is applied to an object's particles as ``x_world = translate + scale·R·x``
  with ``R = Rz(γ) · Ry(β) · Rx(α)`` for ``rotate_deg: [α, β, γ]``, i.e. extrinsic rotations
  about the fixed world axes X, then Y, then Z (scipy's ``from_euler("xyz", ...)``).
* ``placement`` (a trained object's size and orientation in the world) resolves into the
  object's ``transform`` here (:mod:`fracture_gs.config.placement`), so the resolved scene holds
  the transform it stands for.
* ``model`` paths are resolved against the current working directory first, then against
  the folder of the scene file; a folder must contain ``particles.ply`` (a ``train.py``
  output), a file must be a ``.ply`` of particles.
* A material's keys are read and checked by its class (:mod:`fracture_gs.materials`): NACC's α0
  may be given as ``alpha0`` or as the paper's ``Jp0``, M as ``M`` or as ``friction_angle``; the
  resolved scene always holds ``alpha0`` and ``M``.
* An object's initial velocity field about its centre of mass c (after the transform) is
  v(x) = velocity + angular_velocity × (x − c) + velocity_gradient (x − c).
"""
from __future__ import annotations

import math
import os
import re
from collections.abc import Mapping
from dataclasses import InitVar, dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

import yaml

from fracture_gs import bounds
from fracture_gs.config.placement import placement_transform
from fracture_gs.io.model_layout import PARTICLES_FILE
from fracture_gs.materials import Material, material_from_yaml
from fracture_gs.keys import NAME_PATTERN, NAME_RULE, SceneError
from fracture_gs.keys import boolean as _boolean
from fracture_gs.keys import check_keys as _check_keys
from fracture_gs.keys import check_number as _check_number
from fracture_gs.keys import choice as _choice
from fracture_gs.keys import fmt as _fmt
from fracture_gs.keys import integer as _integer
from fracture_gs.keys import join as _join
from fracture_gs.keys import listing as _list
from fracture_gs.keys import mapping as _mapping
from fracture_gs.keys import name as _name
from fracture_gs.keys import number as _number
from fracture_gs.keys import type_name as _type_name
from fracture_gs.keys import vec3 as _vec3

CONTACT_MODES = ("collision", "mls")
BOX_CONDITIONS = ("slip", "sticky", "separate")
SHAPES = ("box", "sphere", "cylinder")

# Defaults of optional keys (the paper's values where it gives them, Table 1; docs/scenes.md).
DEFAULT_FRAMES = 100
DEFAULT_FRAME_DT = 1.0 / 60.0
DEFAULT_GRAVITY = (0.0, 0.0, -9.8)
DEFAULT_CFL = 0.3
DEFAULT_PARTICLES_PER_CELL = 8
DEFAULT_GROUND_FRICTION = 0.5
DEFAULT_FRAGMENTS = False  # contact.fragments (crack opening inside objects, docs/formulas.md §8)


# ----------------------------------------------------------------------------- dataclasses


# Solver settings of contact that the YAML does not expose (docs/design_mpm.md): contact detection,
# in cells (a node is a contact only where the two bodies' mass centres seen from it are closer than
# this along the normal: touching solid bodies are 0.81-0.9 dx apart, touching one-layer sheets their
# particle spacing); the partition's split threshold, in 1/cells (a node is split into two crack sides
# where the largest particle damage gradient reaching it is at least this); and the plastic volume
# dilation by which NACC's α must pass its fracture threshold before the partition treats a particle
# as damaged.
CONTACT_GAP_CELLS = 0.9
SPLIT_GRADIENT_CELLS = 0.25
DAMAGE_DILATION = 0.005


@dataclass(frozen=True)
class Domain:
    """The simulation box (YAML ``domain: {min, max, grid}``): cubic cells of edge
    ``dx = (upper - lower)[0] / grid``. Checked when made (``path``: the key path errors name)."""

    lower: tuple[float, float, float]
    upper: tuple[float, float, float]
    grid: int
    path: InitVar[str] = "domain"

    def __post_init__(self, path: str) -> None:
        given = {"min": self.lower, "max": self.upper, "grid": self.grid}
        lower, upper = _vec3(given, "min", path), _vec3(given, "max", path)
        for axis in range(3):
            if not upper[axis] > lower[axis]:
                raise SceneError(f"{path}.max[{axis}]", f"{_fmt(upper[axis])} is not > {path}.min[{axis}] = "
                                                        f"{_fmt(lower[axis])}")
        object.__setattr__(self, "lower", lower)
        object.__setattr__(self, "upper", upper)
        object.__setattr__(self, "grid", _integer(given, "grid", path, ge=8))

    @property
    def dx(self) -> float:
        return (self.upper[0] - self.lower[0]) / self.grid

    @property
    def size(self) -> float:
        """Largest edge length of the box."""
        return max(hi - lo for lo, hi in zip(self.lower, self.upper))


@dataclass(frozen=True)
class ContactSettings:
    """How objects touch (YAML ``contact: {mode, impulse_scale, friction, fragments}``): per-object grids
    and the contact impulse (``collision``), or one shared grid (``mls``, the baseline). Checked when
    made (``path``: the key path errors name)."""

    mode: Literal["collision", "mls"] = "collision"
    # The paper's μ, the scale of the normal impulse: it leaves (1 - s) of the normal approach speed,
    # so 0 <= s <= 2 (beyond 2 the impulse would add energy).
    impulse_scale: float = 1.0
    friction: float = 0.0        # Coulomb coefficient between objects (tangential cap friction · s · j_n)
    # Crack opening inside an object (docs/formulas.md §8): each object grid is split into two fields
    # along the damage gradient, which meet through the same contact impulse. False: one field per
    # object (the paper's behaviour, kept for the ablation).
    fragments: bool = DEFAULT_FRAGMENTS
    # Not YAML keys (solver settings, docs/design_mpm.md): contact detection in cells (math.inf: every
    # node where both bodies have mass, no detection test), the partition's split threshold in 1/cells,
    # and NACC's dilation past its threshold that makes a particle damaged for the partition.
    max_gap: float = CONTACT_GAP_CELLS
    split_gradient: float = SPLIT_GRADIENT_CELLS
    damage_dilation: float = DAMAGE_DILATION
    path: InitVar[str] = "contact"

    def __post_init__(self, path: str) -> None:
        given = {name: getattr(self, name) for name in ("mode", "impulse_scale", "friction", "fragments", "max_gap",
                                                        "split_gradient", "damage_dilation")}
        checked = {"mode": _choice(given, "mode", path, CONTACT_MODES),
                   "impulse_scale": _number(given, "impulse_scale", path, ge=0.0, le=2.0),
                   "friction": _number(given, "friction", path, ge=0.0),
                   "fragments": _boolean(given, "fragments", path),
                   "max_gap": math.inf if given["max_gap"] == math.inf
                   else _number(given, "max_gap", path, gt=0.0),
                   "split_gradient": _number(given, "split_gradient", path, gt=0.0),
                   "damage_dilation": _number(given, "damage_dilation", path, ge=0.0)}
        for name, value in checked.items():
            object.__setattr__(self, name, value)


@dataclass(frozen=True)
class GroundBoundary:
    """Half-space z >= height with Coulomb friction (YAML ``{type: ground, height, friction}``)."""

    height: float
    friction: float = DEFAULT_GROUND_FRICTION
    path: InitVar[str] = "ground"

    def __post_init__(self, path: str) -> None:
        given = {"height": self.height, "friction": self.friction}
        object.__setattr__(self, "height", _number(given, "height", path))
        object.__setattr__(self, "friction", _number(given, "friction", path, ge=0.0))


@dataclass(frozen=True)
class BoxBoundary:
    """Domain walls, 3 cells thick (YAML ``{type: box, condition}``): slip, sticky or separate."""

    condition: Literal["slip", "sticky", "separate"] = "slip"
    path: InitVar[str] = "box"

    def __post_init__(self, path: str) -> None:
        object.__setattr__(self, "condition", _choice({"condition": self.condition}, "condition", path,
                                                      BOX_CONDITIONS))


Boundary = GroundBoundary | BoxBoundary


@dataclass(frozen=True)
class TransformConfig:
    """x_world = translate + scale · Rz·Ry·Rx · x (rotate_deg = [x, y, z] in degrees)."""

    scale: float = 1.0
    rotate_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    translate: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class PrimitiveConfig:
    """An analytic solid centred at the origin of its object frame (cylinder axis = z)."""

    shape: Literal["box", "sphere", "cylinder"]
    size: tuple[float, float, float] | None = None   # box edge lengths
    radius: float | None = None                      # sphere, cylinder
    height: float | None = None                      # cylinder
    particles_per_cell: int = DEFAULT_PARTICLES_PER_CELL


@dataclass(frozen=True)
class MaterialConfig:
    """Material of one part of an object: the part id and the material (its class holds the keys)."""

    part: int
    material: Material
    interior_colour: tuple[float, float, float] | None = None  # RGB of the faces a fracture opens

    @property
    def model(self) -> str:
        """The model's YAML name (``elastic``, ``nacc``, ``brittle``)."""
        return self.material.name

    @property
    def density(self) -> float:
        return self.material.density


@dataclass(frozen=True)
class ObjectConfig:
    name: str
    materials: tuple[MaterialConfig, ...]
    model: Path | None = None          # absolute path as given (folder or .ply)
    primitive: PrimitiveConfig | None = None
    transform: TransformConfig = TransformConfig()
    velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)
    angular_velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)   # rad/s, about the centre of mass
    velocity_gradient: tuple[tuple[float, float, float], ...] = ((0.0, 0.0, 0.0),) * 3   # 1/s
    rigid: bool = False   # moves as one rigid body (fracture_gs.mpm.rigid); elastic materials only

    @property
    def particles_file(self) -> Path | None:
        """The ``.ply`` with this object's particles (None for a primitive)."""
        if self.model is None:
            return None
        return self.model / PARTICLES_FILE if self.model.is_dir() else self.model


@dataclass(frozen=True)
class SceneConfig:
    """A fully validated scene with every default filled in."""

    name: str
    domain: Domain
    objects: tuple[ObjectConfig, ...]
    frames: int = DEFAULT_FRAMES
    frame_dt: float = DEFAULT_FRAME_DT
    gravity: tuple[float, float, float] = DEFAULT_GRAVITY
    contact: ContactSettings = ContactSettings()
    cfl: float = DEFAULT_CFL
    boundaries: tuple[Boundary, ...] = (BoxBoundary(),)
    seed: int = 0
    source: Path | None = field(default=None, compare=False)

    def to_dict(self) -> dict[str, Any]:
        """Plain-YAML form of the resolved scene; ``parse_scene(to_dict())`` gives it back."""
        return {
            "name": self.name,
            "domain": {"min": list(self.domain.lower), "max": list(self.domain.upper),
                       "grid": self.domain.grid},
            "frames": self.frames,
            "frame_dt": self.frame_dt,
            "gravity": list(self.gravity),
            "contact": {"mode": self.contact.mode, "impulse_scale": self.contact.impulse_scale,
                        "friction": self.contact.friction, "fragments": self.contact.fragments},
            "cfl": self.cfl,
            "seed": self.seed,
            "boundaries": [_boundary_dict(b) for b in self.boundaries],
            "objects": [_object_dict(o) for o in self.objects],
        }


def _boundary_dict(boundary: Boundary) -> dict[str, Any]:
    if isinstance(boundary, GroundBoundary):
        return {"type": "ground", "height": boundary.height, "friction": boundary.friction}
    return {"type": "box", "condition": boundary.condition}


def _object_dict(obj: ObjectConfig) -> dict[str, Any]:
    out: dict[str, Any] = {"name": obj.name}
    if obj.model is not None:
        out["model"] = str(obj.model)
    else:
        assert obj.primitive is not None
        prim = obj.primitive
        p: dict[str, Any] = {"shape": prim.shape}
        if prim.shape == "box":
            p["size"] = list(prim.size or ())
        else:
            p["radius"] = prim.radius
            if prim.shape == "cylinder":
                p["height"] = prim.height
        p["particles_per_cell"] = prim.particles_per_cell
        out["primitive"] = p
    out["transform"] = {"scale": obj.transform.scale,
                        "rotate_deg": list(obj.transform.rotate_deg),
                        "translate": list(obj.transform.translate)}
    out["velocity"] = list(obj.velocity)
    out["angular_velocity"] = list(obj.angular_velocity)
    out["velocity_gradient"] = [list(row) for row in obj.velocity_gradient]
    if obj.rigid:   # written only when set, so scenes saved before the key existed still compare equal
        out["rigid"] = True
    out["materials"] = [{"part": m.part, **m.material.to_yaml(),
                         **({"interior_colour": list(m.interior_colour)} if m.interior_colour else {})}
                        for m in obj.materials]
    return out


# ----------------------------------------------------------------------------- YAML reading


class _SceneLoader(yaml.SafeLoader):
    """SafeLoader that also reads YAML 1.2 floats such as ``5.0e5`` or ``1e4`` as numbers and
    refuses a key given twice in one mapping (PyYAML would keep the last value silently)."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        seen: dict[Any, yaml.Node] = {}
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                continue  # '<<' merges are resolved by the base class
            key = self.construct_object(key_node, deep=deep)
            try:
                first = seen.setdefault(key, key_node)
            except TypeError:
                continue  # an unhashable key: the base class reports it
            if first is not key_node:
                raise yaml.constructor.ConstructorError(
                    None, None, f"duplicate key '{key}' (first given at line "
                    f"{first.start_mark.line + 1})", key_node.start_mark)
        return super().construct_mapping(node, deep=deep)


_SceneLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
                   |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
                   |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
                   |[-+]?\.(?:inf|Inf|INF)
                   |\.(?:nan|NaN|NAN))$""", re.X),
    list("-+0123456789."))


def read_yaml(path: str | os.PathLike[str]) -> Any:
    """Parse a YAML file (``5.0e5`` is a float); errors name the file."""
    path = Path(path)
    try:
        text = path.read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise SceneError(str(path), "file not found") from None
    except OSError as exc:
        raise SceneError(str(path), f"cannot read ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        raise SceneError(str(path), f"not a YAML text file (byte {exc.start} is not UTF-8)") \
            from None
    try:
        return yaml.load(text, Loader=_SceneLoader)  # noqa: S506 - SafeLoader subclass
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise SceneError(str(path), f"invalid YAML{where}: {problem}") from None
    except RecursionError:  # the parser recurses once per level of '[' / '{' / indentation
        raise SceneError(str(path), "invalid YAML: lists or mappings nested too deeply "
                                    "(hundreds of levels)") from None


def load_scene(path: str | os.PathLike[str]) -> SceneConfig:
    """Read and validate a scene file; raises :class:`SceneError` naming the bad key."""
    path = Path(path)
    data = read_yaml(path)
    if data is None:
        raise SceneError(str(path), "the file holds no scene (empty YAML document)")
    return parse_scene(data, base_dir=path.parent, default_name=path.stem, source=path)


# ----------------------------------------------------------------------------- validation


_TOP_KEYS = ("name", "domain", "frames", "frame_dt", "gravity", "contact", "cfl", "boundaries",
             "objects", "seed")


def parse_scene(data: Any, *, base_dir: str | os.PathLike[str] | None = None,
                default_name: str | None = None, source: Path | None = None) -> SceneConfig:
    """Validate a parsed scene mapping and fill in defaults.

    ``base_dir`` is the second place relative ``model`` paths are looked up (after the
    working directory); ``default_name`` is used when the scene has no ``name``.
    """
    data = _mapping(data, "")
    _check_keys(data, "", _TOP_KEYS, required=("domain", "objects"))
    if "name" in data:
        name = _name(data["name"], "name")
    elif default_name is not None:
        name = _default_name(default_name, source)
    else:
        raise SceneError("name", "required key is missing")
    domain = _parse_domain(data["domain"])
    frames = _integer(data, "frames", "", DEFAULT_FRAMES, ge=1, le=bounds.FRAMES_MAX)
    frame_dt = _number(data, "frame_dt", "", DEFAULT_FRAME_DT, gt=0.0, within=bounds.FRAME_DT)
    gravity = _vec3(data, "gravity", "", DEFAULT_GRAVITY, within=bounds.GRAVITY)
    contact = _parse_contact(data.get("contact", {}))
    cfl = _number(data, "cfl", "", DEFAULT_CFL, gt=0.0, le=1.0)
    seed = _integer(data, "seed", "", 0, ge=0, le=bounds.SEED_MAX)
    boundaries = _parse_boundaries(_list(data, "boundaries", "", [{"type": "box"}]), domain)
    raw_objects = _list(data, "objects", "")
    if not raw_objects:
        raise SceneError("objects", "at least one object is required")
    base = Path(base_dir) if base_dir is not None else None
    objects = tuple(_parse_object(o, f"objects[{i}]", i, base) for i, o in enumerate(raw_objects))
    ground = next((b.height for b in boundaries if isinstance(b, GroundBoundary)), None)
    objects = tuple(_placed(obj, raw, f"objects[{i}]", ground)
                    for i, (obj, raw) in enumerate(zip(objects, raw_objects)))
    seen: dict[str, int] = {}
    for i, obj in enumerate(objects):
        if obj.name in seen:
            raise SceneError(f"objects[{i}].name",
                             f"'{obj.name}' is already the name of objects[{seen[obj.name]}]")
        seen[obj.name] = i
    return SceneConfig(name=name, domain=domain, objects=objects, frames=frames,
                       frame_dt=frame_dt, gravity=gravity, contact=contact, cfl=cfl,
                       boundaries=boundaries, seed=seed, source=source)


def _default_name(default_name: str, source: Path | None) -> str:
    """The scene's name taken from its file name; an error that says what to do when the file
    name is not a valid name."""
    if NAME_PATTERN.match(default_name):
        return default_name
    raise SceneError(str(source) if source is not None else "name",
                     f"the scene has no 'name' key and its file name {_fmt(default_name)} is not "
                     f"a valid name ({NAME_RULE}); add a 'name:' line to the scene or rename "
                     "the file")


def _parse_domain(value: Any) -> Domain:
    data = _mapping(value, "domain")
    _check_keys(data, "domain", ("min", "max", "grid"), required=("min", "max", "grid"))
    return Domain(lower=data["min"], upper=data["max"], grid=data["grid"])


# Keys renamed since scenes were first written: the old name gets a line that names the new one.
_RENAMED_CONTACT_KEYS = {"strength": "impulse_scale"}


def _parse_contact(value: Any) -> ContactSettings:
    data = _mapping(value, "contact")
    for old, new in _RENAMED_CONTACT_KEYS.items():
        if old in data:
            raise SceneError(f"contact.{old}", f"this key is now called '{new}' (the same meaning and values)")
    _check_keys(data, "contact", ("mode", "impulse_scale", "friction", "fragments"))
    given = {key: data[key] for key in ("mode", "impulse_scale", "friction", "fragments") if key in data}
    return ContactSettings(**given)


def _parse_boundaries(items: list[Any], domain: Domain) -> tuple[Boundary, ...]:
    out: list[Boundary] = []
    seen: dict[str, int] = {}
    for i, item in enumerate(items):
        path = f"boundaries[{i}]"
        data = _mapping(item, path)
        kind = _choice(data, "type", path, ("ground", "box"))
        if kind in seen:
            raise SceneError(f"{path}.type",
                             f"a second '{kind}' boundary (boundaries[{seen[kind]}] is one)")
        seen[kind] = i
        if kind == "ground":
            _check_keys(data, path, ("type", "height", "friction"), required=("height",))
            height = _number(data, "height", path, ge=domain.lower[2], lt=domain.upper[2])
            out.append(GroundBoundary(height=height, friction=data.get("friction", DEFAULT_GROUND_FRICTION),
                                      path=path))
        else:
            _check_keys(data, path, ("type", "condition"))
            out.append(BoxBoundary(condition=data.get("condition", "slip"), path=path))
    return tuple(out)


def _parse_object(value: Any, path: str, index: int, base_dir: Path | None) -> ObjectConfig:
    data = _mapping(value, path)
    _check_keys(data, path, ("name", "model", "primitive", "transform", "placement", "velocity",
                             "angular_velocity", "velocity_gradient", "rigid", "materials"),
                required=("materials",))
    name = _name(data["name"], f"{path}.name") if "name" in data else f"object{index}"
    has_model, has_primitive = "model" in data, "primitive" in data
    if has_model == has_primitive:
        raise SceneError(path, "exactly one of 'model' and 'primitive' is required"
                         + (" (both given)" if has_model else ""))
    model = _resolve_model(data["model"], f"{path}.model", base_dir) if has_model else None
    primitive = _parse_primitive(data["primitive"], f"{path}.primitive") if has_primitive \
        else None
    transform = _parse_transform(data.get("transform", {}), f"{path}.transform")
    velocity = _vec3(data, "velocity", path, (0.0, 0.0, 0.0), within=bounds.VELOCITY)
    angular_velocity = _vec3(data, "angular_velocity", path, (0.0, 0.0, 0.0),
                             within=bounds.ANGULAR_VELOCITY)
    velocity_gradient = _matrix3(data, "velocity_gradient", path, ((0.0, 0.0, 0.0),) * 3,
                                 within=bounds.VELOCITY_GRADIENT)
    raw_materials = _list(data, "materials", path)
    if not raw_materials:
        raise SceneError(f"{path}.materials", "at least one material is required")
    materials = tuple(_parse_material(m, f"{path}.materials[{j}]")
                      for j, m in enumerate(raw_materials))
    parts: dict[int, int] = {}
    for j, mat in enumerate(materials):
        if mat.part in parts:
            raise SceneError(f"{path}.materials[{j}].part",
                             f"part {mat.part} already has a material "
                             f"(materials[{parts[mat.part]}])")
        parts[mat.part] = j
    rigid = _boolean(data, "rigid", path, False)
    if rigid:
        for j, mat in enumerate(materials):
            if mat.model != "elastic":
                raise SceneError(f"{path}.materials[{j}].model",
                                 f"a rigid object neither deforms nor breaks: give its parts the elastic model "
                                 f"(its density sets the mass), not {mat.model!r}")
    return ObjectConfig(name=name, materials=materials, model=model, primitive=primitive,
                        transform=transform, velocity=velocity, angular_velocity=angular_velocity,
                        velocity_gradient=velocity_gradient, rigid=rigid)


def _placed(obj: ObjectConfig, raw: Any, path: str, ground: float | None) -> ObjectConfig:
    """``obj`` with the transform its ``placement`` resolves to (:mod:`fracture_gs.config.placement`)."""
    placed = placement_transform(raw, path, obj.model, ground)
    if placed is None:
        return obj
    scale, rotate_deg, translate = placed
    return replace(obj, transform=TransformConfig(scale=scale, rotate_deg=rotate_deg,
                                                  translate=translate))


def _matrix3(data: Mapping[str, Any], key: str, path: str,
             default: tuple[tuple[float, float, float], ...],
             within: tuple[float, float]) -> tuple[tuple[float, float, float], ...]:
    """A 3×3 matrix given as a list of 3 rows of 3 numbers, each ``within`` its bounds."""
    keypath = _join(path, key)
    if key not in data:
        return default
    value = data[key]
    if not isinstance(value, list) or len(value) != 3 or not all(isinstance(r, list) for r in value):
        raise SceneError(keypath, f"expected a 3x3 matrix (a list of 3 rows of 3 numbers), got {_type_name(value)}")
    rows = []
    for i, row in enumerate(value):
        if len(row) != 3:
            raise SceneError(f"{keypath}[{i}]", f"expected a row of 3 numbers, got {len(row)} entries")
        rows.append(tuple(_check_number(v, f"{keypath}[{i}][{j}]", within=within)
                          for j, v in enumerate(row)))
    return tuple(rows)  # type: ignore[return-value]


def _resolve_model(value: Any, keypath: str, base_dir: Path | None) -> Path:
    if not isinstance(value, str) or not value:
        raise SceneError(keypath, f"expected a path, got {_type_name(value)}")
    given = Path(value).expanduser()
    candidates = [given] if given.is_absolute() else \
        [Path.cwd() / given] + ([base_dir / given] if base_dir is not None else [])
    found = next((c for c in candidates if c.exists()), None)
    if found is None:
        raise SceneError(keypath, f"'{value}' does not exist")
    found = found.resolve()
    particles = found / PARTICLES_FILE if found.is_dir() else found
    if found.is_dir() and not particles.is_file():
        raise SceneError(keypath, f"'{value}' has no {PARTICLES_FILE} (not a train.py output)")
    if particles.suffix.lower() != ".ply":
        raise SceneError(keypath, f"'{value}' is neither a train.py output folder nor a .ply")
    try:
        with open(particles, "rb") as handle:
            head = handle.read(4)
    except OSError as exc:
        raise SceneError(keypath, f"cannot read '{particles}' ({exc.strerror})") from None
    if head[:3] != b"ply":
        raise SceneError(keypath, f"'{particles}' is not a PLY file")
    return found


def _parse_primitive(value: Any, path: str) -> PrimitiveConfig:
    data = _mapping(value, path)
    shape = _choice(data, "shape", path, SHAPES)
    ppc = ("particles_per_cell",)
    if shape == "box":
        _check_keys(data, path, ("shape", "size") + ppc, required=("size",))
        prim = PrimitiveConfig(shape="box", size=_vec3(data, "size", path, gt=0.0))
    elif shape == "sphere":
        _check_keys(data, path, ("shape", "radius") + ppc, required=("radius",))
        prim = PrimitiveConfig(shape="sphere", radius=_number(data, "radius", path, gt=0.0))
    else:
        _check_keys(data, path, ("shape", "radius", "height") + ppc,
                    required=("radius", "height"))
        prim = PrimitiveConfig(shape="cylinder", radius=_number(data, "radius", path, gt=0.0),
                               height=_number(data, "height", path, gt=0.0))
    count = _integer(data, "particles_per_cell", path, DEFAULT_PARTICLES_PER_CELL, ge=1)
    return PrimitiveConfig(shape=prim.shape, size=prim.size, radius=prim.radius,
                           height=prim.height, particles_per_cell=count)


def _parse_transform(value: Any, path: str) -> TransformConfig:
    data = _mapping(value, path)
    _check_keys(data, path, ("scale", "rotate_deg", "translate"))
    return TransformConfig(scale=_number(data, "scale", path, 1.0, gt=0.0),
                           rotate_deg=_vec3(data, "rotate_deg", path, (0.0, 0.0, 0.0)),
                           translate=_vec3(data, "translate", path, (0.0, 0.0, 0.0)))


def _parse_material(value: Any, path: str) -> MaterialConfig:
    data = _mapping(value, path)
    colour = _vec3(data, "interior_colour", path, None)
    if colour is not None and not all(0.0 <= c <= 1.0 for c in colour):
        raise SceneError(f"{path}.interior_colour", f"{list(colour)}: each channel must be in [0, 1]")
    material = material_from_yaml({key: v for key, v in data.items() if key != "interior_colour"}, path)
    return MaterialConfig(part=_integer(data, "part", path, 0, ge=0), material=material, interior_colour=colour)
