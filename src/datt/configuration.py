"""Config composition helpers shared by every layer: where the config tree lives, the options of
a group, one-line errors for Hydra/OmegaConf failures, typed schemas and ``_target_`` building.

The config tree is package data (``datt/conf``, found through the package, so a wheel works).
Inside a Hydra job the search path is Hydra's own (``--config-dir``, ``hydra.searchpath``), so a
user's options are found everywhere a group is listed or loaded.
"""

from __future__ import annotations

import contextlib
import math
import re
import secrets
import typing
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field, fields, is_dataclass
from importlib import resources
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, ListConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from datt.errors import ConfigError, one_line

CONF_PACKAGE = "datt.conf"
# ``${uid:}`` in run/sweep dir names: random per command, cached like Hydra's ``${now:}`` so every
# job of a multirun resolves the same sweep dir.
if not OmegaConf.has_resolver("uid"):
    OmegaConf.register_new_resolver("uid", lambda: secrets.token_hex(2), use_cache=True)

# groups Hydra owns (hydra/launcher, hydra/sweeper ...): never checked against our options
HYDRA_GROUPS = frozenset({"hydra"})


def conf_dir() -> Path:
    """The package's config tree on disk (``site-packages/datt/conf`` or ``src/datt/conf``)."""
    return Path(str(resources.files(CONF_PACKAGE)))


def root_from_uri(uri: str, base: Path | None = None) -> Path | None:
    """A search-path entry (``file://dir``, ``pkg://module``, or a plain dir) as a directory."""
    if uri.startswith("pkg://"):
        module = uri[len("pkg://") :].strip("/").replace("/", ".")
        try:
            return Path(str(resources.files(module)))
        except (ModuleNotFoundError, TypeError):
            return None
    path = Path(uri[len("file://") :] if uri.startswith("file://") else uri).expanduser()
    if not path.is_absolute():
        path = (base or Path.cwd()) / path
    return path


# the command line being checked before its job starts: (search roots, overrides)
_PREFLIGHT: list[tuple[list[Path], list[str]]] = []


@contextlib.contextmanager
def preflight_command(roots: list[Path], overrides: list[str]) -> Iterator[None]:
    """While a command line is checked before its job starts, :func:`search_roots` is ``roots``
    (its ``--config-dir`` and ``hydra.searchpath`` before the package's tree) and
    :func:`command_overrides` its ``overrides``, as they will be inside the job."""
    _PREFLIGHT.append((list(roots), list(overrides)))
    try:
        yield
    finally:
        _PREFLIGHT.pop()


def command_overrides() -> list[str] | None:
    """The overrides of the running Hydra job, without ``hydra.*`` (None outside Hydra)."""
    try:
        from hydra.core.hydra_config import HydraConfig

        return [o for o in HydraConfig.get().overrides.task if not o.lstrip("+~").startswith("hydra")]
    except (ImportError, ValueError):
        return [o for o in _PREFLIGHT[-1][1] if not o.lstrip("+~").startswith("hydra")] if _PREFLIGHT else None


def search_roots() -> list[Path]:
    """Directories of the current config search path: Hydra's (inside a job), the command
    line's (while it is checked before the job) or the package's."""
    try:
        from hydra.core.hydra_config import HydraConfig

        sources = HydraConfig.get().runtime.config_sources
    except (ImportError, ValueError):
        return _PREFLIGHT[-1][0] if _PREFLIGHT else [conf_dir()]
    roots = []
    for src in sources:
        if src.schema in ("file", "pkg") and src.provider not in ("hydra", "schema"):
            root = root_from_uri(f"{src.schema}://{src.path}")
            if root is not None and root.is_dir():
                roots.append(root)
    return roots or [conf_dir()]


def available_options(group: str, roots: list[Path] | None = None) -> list[str]:
    """Names of the YAML options of a config group over the search path."""
    names: set[str] = set()
    for root in roots or search_roots():
        names.update(p.stem for p in (root / group).glob("*.yaml"))
    return sorted(names)


def config_groups(roots: list[Path] | None = None) -> set[str]:
    """Top-level config groups over the search path (directories holding YAML)."""
    return {
        p.name
        for root in roots or search_roots()
        if root.is_dir()
        for p in root.iterdir()
        if p.is_dir() and any(p.glob("*.yaml")) and p.name not in HYDRA_GROUPS
    }


def load_option(group: str, name: str) -> DictConfig:
    """One option of a config group as Hydra composes it (``<root>/<group>/<name>.yaml``, first
    root wins, as in Hydra: the user's config dir before the package's), its own defaults list
    included: ``- other`` and ``- other@key`` (an option of the same group, at the option's root
    or under ``key``), ``- sub@_here_: other`` / ``- sub@key: other`` (an option of the subgroup
    ``<group>/sub``) and ``_self_`` (where the file's own keys merge; last when not listed)."""
    roots = search_roots()
    for root in roots:
        path = root / group / f"{name}.yaml"
        if path.is_file():
            return _compose_option(group, path, roots)
    raise ConfigError(f"{group}: unknown option {name!r}; allowed: {', '.join(available_options(group, roots))}")


def _compose_option(group: str, path: Path, roots: list[Path]) -> DictConfig:
    node = OmegaConf.load(path)
    assert isinstance(node, DictConfig)
    defaults = node.pop("defaults", None) or []
    parts: list[DictConfig] = []
    if "_self_" not in defaults:
        defaults = [*defaults, "_self_"]
    for entry in defaults:
        if entry == "_self_":
            parts.append(node)
            continue
        if isinstance(entry, str):
            sub_group, (option, _, key) = group, entry.partition("@")
        elif isinstance(entry, DictConfig) and len(entry) == 1 and not str(next(iter(entry))).startswith("override"):
            head, option = next(iter(entry.items()))
            sub, _, key = str(head).partition("@")
            sub_group, key = f"{group}/{sub}", key or sub
        else:
            raise ConfigError(
                f"{path}: defaults entry {entry!r} is not one an option can hold "
                "(other, other@key, sub@key: other, _self_)"
            )
        loaded = load_option(sub_group, str(option))
        parts.append(loaded if key in ("", "_here_") else _nest(key, loaded))
    return OmegaConf.merge(*parts)


def _nest(key: str, node: DictConfig) -> DictConfig:
    """``node`` under the dotted ``key`` (``families.poly``)."""
    for part in reversed(key.split(".")):
        node = OmegaConf.create({part: node})
    return node


def check_option(group: str, name: Any, key: str) -> None:
    """``name`` is an option of config group ``group`` (over the search path); else one line
    naming ``key`` and the allowed options."""
    allowed = available_options(group)
    if not isinstance(name, str) or name not in allowed:
        raise ConfigError(f"{key}: unknown value {name!r}; allowed: {', '.join(allowed)}")


def with_options(cfg: DictConfig, **choices) -> DictConfig:
    """Copy of ``cfg`` with whole option nodes swapped: a name loads ``<group>/<name>.yaml``
    (``with_options(cfg, disturbance="none")``), a mapping is used as the node itself."""
    out = OmegaConf.create(OmegaConf.to_container(cfg, resolve=True))
    OmegaConf.set_struct(out, False)
    for group, choice in choices.items():
        out[group] = load_option(group, choice) if isinstance(choice, str) else choice
    return out


@dataclass(frozen=True)
class Range:
    """The values a schema field accepts, declared once per field with :func:`ranged` (or per
    constructor argument in a class's ``ARG_RANGES``) and checked by :func:`check_ranges`.

    Numbers: finite, within ``low``..``high`` (each bound open or closed), whole numbers when
    ``integer``. ``choices``: the field is one of these values instead (names such as
    ``first_order``). ``optional``: None is accepted too. A list field: every element, and the
    list holds ``length`` elements when given (else at least one)."""

    low: float = -math.inf
    high: float = math.inf
    low_open: bool = False
    high_open: bool = False
    optional: bool = False
    integer: bool = False
    choices: tuple = ()
    length: int | None = None

    def accepts(self, value: Any) -> bool:
        if value is None:
            return self.optional
        if self.choices:
            return value in self.choices
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            return False
        if self.integer and not float(value).is_integer():
            return False
        above = value > self.low if self.low_open else value >= self.low
        below = value < self.high if self.high_open else value <= self.high
        return above and below

    def text(self) -> str:
        if self.choices:
            return "one of " + ", ".join(str(c) for c in self.choices) + (" or null" if self.optional else "")
        kind = "an integer" if self.integer else "a finite number"
        low, high = self.low > -math.inf, self.high < math.inf
        if low and high:
            left, right = "(" if self.low_open else "[", ")" if self.high_open else "]"
            bounds = f" in {left}{_number(self.low)}, {_number(self.high)}{right}"
        elif low:
            bounds = f" {'>' if self.low_open else '>='} {_number(self.low)}"
        elif high:
            bounds = f" {'<' if self.high_open else '<='} {_number(self.high)}"
        else:
            bounds = ""
        return kind + bounds + (" or null" if self.optional else "")

    def check(self, value: Any, key: str) -> None:
        """One ConfigError naming ``key``, the value and the allowed values, unless ``value``
        (a list: each element) is allowed."""
        if isinstance(value, (list, tuple)) and not self.choices:
            size_ok = len(value) == self.length if self.length is not None else bool(value)
            if not size_ok or not all(self.accepts(v) for v in value):
                size = f"{self.length} elements" if self.length is not None else "a list"
                raise ConfigError(f"{key}: must be {size}, each {self.text()}, got {list(value)!r}")
        elif self.choices and not self.accepts(value):
            allowed = ", ".join(str(c) for c in self.choices) + (", null" if self.optional else "")
            raise ConfigError(f"{key}: unknown value {value!r}; allowed: {allowed}")
        elif not self.accepts(value):
            raise ConfigError(f"{key}: must be {self.text()}, got {value!r}")


def _number(x: float) -> str:
    """A bound as a reader writes it: 1024, 0.5, 1e-05 (not 1.024e+03)."""
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e16 else f"{x:g}"


def ranged(default: Any, rng: Range, **kwargs: Any) -> Any:
    """A dataclass field whose values must lie in ``rng`` (a list default: each element)."""
    if isinstance(default, list):
        return field(default_factory=lambda: list(default), metadata={"range": rng}, **kwargs)
    return field(default=default, metadata={"range": rng}, **kwargs)


def check_ranges(obj: Any, key: str) -> None:
    """Every field of the dataclass ``obj`` declared with :func:`ranged` holds allowed values,
    nested dataclasses included; else one ConfigError naming the key, the value and the
    allowed range."""
    for f in fields(obj):
        value = getattr(obj, f.name)
        rng = f.metadata.get("range")
        if rng is not None:
            rng.check(value, f"{key}.{f.name}" if key else f.name)
        elif is_dataclass(value) and not isinstance(value, type):
            check_ranges(value, f"{key}.{f.name}" if key else f.name)


def check_arg_ranges(cls: type, args: dict[str, Any], key: str) -> None:
    """The constructor arguments ``args`` of ``cls`` (a ``_target_``) against the ranges the
    class declares in ``ARG_RANGES`` (its bases' too): one ConfigError naming ``key.<arg>``."""
    ranges: dict[str, Range] = {}
    for base in reversed(cls.__mro__):
        ranges.update(getattr(base, "ARG_RANGES", None) or {})
    try:
        hints = typing.get_type_hints(cls.__init__)
    except Exception:  # an annotation that does not resolve: no type to check against
        hints = {}
    for name, value in args.items():
        if hints.get(name) is bool and not isinstance(value, bool):
            raise ConfigError(f"{key}.{name}: must be true or false, got {value!r}")
        if name not in ranges:
            continue
        if isinstance(value, Mapping):  # a mapping argument (weights per family): each value
            for sub, item in value.items():
                ranges[name].check(item, f"{key}.{name}.{sub}")
        else:
            ranges[name].check(value, f"{key}.{name}")


# Every numeric range has two finite bounds (tests/test_config_fuzz.py walks them all): a range that
# only says "finite" lets a finite value switch off what the key feeds (a geofence of 1e30 m, a
# timeout of 1e30 s). The kinds of quantity below carry the bound a person could mean, each with
# its reason; a field with a tighter meaning declares its own.
DISTANCE_M = Range(0.0, 20.0)  # a flight room's extent (metres)
POSITION_M = Range(-20.0, 20.0)  # a point of a flight room: a fence or start beyond 20 m is in no room
LENGTH_M = Range(0.0, 20.0, low_open=True)
SPEED_MPS = Range(0.0, 20.0)  # a Crazyflie flies 1-5 m/s; 20 m/s is beyond any indoor flight
POSITIVE_SPEED_MPS = Range(0.0, 20.0, low_open=True)
ACCEL_MPS2 = Range(0.0, 200.0)  # 20 g: beyond any quadrotor's motors
POSITIVE_ACCEL_MPS2 = Range(0.0, 200.0, low_open=True)
GRAVITY_MPS2 = Range(0.1, 30.0)  # from a small moon's to Jupiter's surface
RATE_RADPS = Range(0.0, 100.0, low_open=True)  # beyond any gyro's full scale (a Crazyflie's: 34.9 rad/s)
TIME_S = Range(0.0, 3600.0)  # durations and time constants: an hour is longer than any flight or episode
POSITIVE_TIME_S = Range(0.0, 3600.0, low_open=True)
WEIGHT = Range(0.0, 1000.0)  # a cost weight, gain or scale: above 1e3 it swamps every other term
POSITIVE_WEIGHT = Range(0.0, 1000.0, low_open=True)
MASS_KG = Range(0.005, 5.0, low_open=True)  # a micro quadrotor's to a large one's
MOTOR_THRUST_N = Range(0.0, 10.0, low_open=True)  # one motor's force: 10 N lifts a kilogram-class vehicle
# an Adam step size above 10 leaves every scale of the data (1e-5..1e-2 is what trains)
LEARNING_RATE = Range(0.0, 10.0, low_open=True)
NOISE = Range(0.0, 10.0)  # a noise std (m, m/s, rad): beyond 10 there is no measurement left
UNIT_INTERVAL = Range(0.0, 1.0)
FRACTION = Range(0.0, 1.0, low_open=True)  # (0, 1]
# Counts get a ceiling as well: a typo of a few zeros must be one line, not an hour of
# allocation and an out-of-memory kill.
COUNT = Range(1, 1e12, integer=True)
NON_NEGATIVE_COUNT = Range(0, 1e12, integer=True)
SEED = Range(0, 2**32 - 1, integer=True)  # what numpy, torch and Python all accept
BATCH = Range(1, 1 << 20, integer=True)  # drones in one tensor, minibatch sizes
THREADS = Range(1, 1024, integer=True)


def check_bools(cls: type, node: Any, key: str) -> None:
    """A field typed ``bool`` takes true or false only (``bool | None``: also null): OmegaConf
    would turn ``1``, ``0`` or ``"yes"`` into a bool, and the run would record one value and use
    another."""
    if isinstance(node, DictConfig):
        node = OmegaConf.to_container(node, resolve=True)
    if not isinstance(node, Mapping):
        return
    hints = typing.get_type_hints(cls)
    for f in fields(cls):
        if f.name not in node:
            continue
        value, hint = node[f.name], hints.get(f.name)
        where = f"{key}.{f.name}" if key else f.name
        if hint is bool and not isinstance(value, bool):
            raise ConfigError(f"{where}: must be true or false, got {value!r}")
        if hint == (bool | None) and not (value is None or isinstance(value, bool)):
            raise ConfigError(f"{where}: must be true, false or null, got {value!r}")
        if isinstance(hint, type) and is_dataclass(hint):
            check_bools(hint, value, where)


def structured(cls, node, key: str):
    """Merge ``node`` onto the dataclass schema ``cls`` (type-checked; a field the YAML does not
    give is an error), build it and call its ``validate()``; errors become one-line
    ConfigErrors under ``key`` (``""``: the node is the config's top level)."""
    check_bools(cls, node, key)
    try:
        merged = OmegaConf.merge(OmegaConf.structured(cls), node or {})
        obj = OmegaConf.to_object(merged)
    except OmegaConfBaseException as exc:
        sub = getattr(exc, "full_key", "") or ""
        where = ".".join(k for k in (key, sub) if k) or cls.__name__
        raise ConfigError(f"{where}: {one_line(exc)}") from None
    check_ranges(obj, key)
    obj.validate()
    return obj


# Keys that no longer exist: the old spelling -> what to use instead. A command line that names
# one is refused in one line (:func:`refuse_retired_keys`); a config read from a checkpoint or a run
# dir is carried over (:func:`upgrade_saved_config`: a renamed key's value moves, a dead key goes).
RETIRED_KEYS: dict[str, str] = {
    "env.num_envs": "algo.num_envs (training) or rma.num_envs (RMA fitting); evaluation, export and "
    "deployment size their own batches",
    "train.threads": "threads",
    "train.total_steps": "train.total_frames (the same number: frames, env steps summed over the drones)",
    "curriculum.fixed_ref_steps": "curriculum.fixed_ref_frames (the same number: frames)",
    "train.phases": "train.stages (the same list: a training schedule in stages)",
    "stage": "python fit_rma.py base_checkpoint=<policy> to fit an RMA adapter (stage=rma); python train.py trains",
    "eval.seed": "eval.seeds (a list, as in eval.py: eval.seeds=[0] or [0,1,2])",
}
# the retired keys whose value moves
RENAMED_KEYS: dict[str, str] = {
    "train.threads": "threads",
    "train.total_steps": "train.total_frames",
    "curriculum.fixed_ref_steps": "curriculum.fixed_ref_frames",
    "train.phases": "train.stages",
    "eval.seed": "eval.seeds",
}
# a renamed key whose value changes shape as it moves
RENAMED_VALUES: dict[str, Callable[[Any], Any]] = {"eval.seed": lambda seed: [seed]}
# keys a saved training config may still hold from when train.py also fitted RMA adapters: dropped
FIT_RMA_KEYS_IN_SAVED_TRAIN_CONFIGS = ("base_checkpoint", "rma")


def refuse_retired_keys(overrides: list[str]) -> None:
    """A command-line override of a retired key is one line naming what replaced it."""
    for text in overrides:
        key = text.lstrip("+~").partition("=")[0]
        if key in RETIRED_KEYS:
            raise ConfigError(f"{key}: no longer a setting; use {RETIRED_KEYS[key]}")


def upgrade_saved_config(cfg: DictConfig) -> DictConfig:
    """A config saved by an older run (checkpoint ``config_yaml`` or a run's ``config.yaml``),
    in place, in today's keys: renamed keys moved (today's value kept if both are there), dead
    keys dropped. Returns ``cfg``."""
    with contextlib.ExitStack() as stack:
        if OmegaConf.is_struct(cfg):
            stack.enter_context(_unstructed(cfg))
        for key in RETIRED_KEYS:
            parent_key, _, leaf = key.rpartition(".")
            parent = OmegaConf.select(cfg, parent_key, default=None) if parent_key else cfg
            if not isinstance(parent, DictConfig) or leaf not in parent:
                continue
            value = parent[leaf]
            del parent[leaf]
            new = RENAMED_KEYS.get(key)
            if new is not None and OmegaConf.select(cfg, new, default="absent") == "absent":
                OmegaConf.update(cfg, new, RENAMED_VALUES.get(key, lambda v: v)(value), force_add=True)
        if "train" in cfg:  # a training run's config
            for key in FIT_RMA_KEYS_IN_SAVED_TRAIN_CONFIGS:
                cfg.pop(key, None)
            for stage in OmegaConf.select(cfg, "train.stages", default=None) or []:
                if isinstance(stage, DictConfig) and "steps" in stage and "frames" not in stage:
                    stage["frames"] = stage.pop("steps")  # a stage's length: frames, once named steps
    return cfg


@contextlib.contextmanager
def _unstructed(cfg: DictConfig) -> Iterator[None]:
    OmegaConf.set_struct(cfg, False)
    try:
        yield
    finally:
        OmegaConf.set_struct(cfg, True)


def flat_leaves(tree: Any, prefix: str = "") -> dict[str, object]:
    """A nested config container (dicts of dicts) as ``{"dotted.key": leaf value}``."""
    if isinstance(tree, dict):
        out: dict[str, object] = {}
        for key, value in tree.items():
            out.update(flat_leaves(value, f"{prefix}{key}."))
        return out
    return {prefix[:-1]: tree}


HORIZON = Range(1, 1000, integer=True)  # future reference points the policy reads


def check_horizon(horizon: Any) -> int:
    """The policy horizon H (number of future reference points)."""
    if isinstance(horizon, float) or not HORIZON.accepts(horizon):
        raise ConfigError(f"horizon: must be {HORIZON.text()} (number of future reference points), got {horizon!r}")
    return horizon


_TARGET_LINE = re.compile(r"_target_\s*:\s*['\"]?([A-Za-z_][\w.]*)")
_TARGETS_CACHE: dict[tuple[Path, ...], frozenset[str]] = {}


def registered_targets(roots: list[Path] | None = None) -> frozenset[str]:
    """Every ``_target_`` written in a YAML file of the config search path (the package's config
    tree and a user's ``--config-dir``): the only classes and functions a config may build. A
    user registers their own by writing an option for it in their config dir."""
    key = tuple(roots or search_roots())
    if key not in _TARGETS_CACHE:
        found: set[str] = set()
        for root in key:
            for path in sorted(root.rglob("*.yaml")) if root.is_dir() else []:
                found.update(_TARGET_LINE.findall(path.read_text(errors="replace")))
        _TARGETS_CACHE[key] = frozenset(found)
    return _TARGETS_CACHE[key]


def _dict_nodes(node: Any, where: str, resolve: bool) -> Iterator[tuple[str, dict]]:
    """Every mapping in the config tree ``node`` (through lists), with its dotted key."""
    stack: list[tuple[str, Any]] = [(where, node)]
    while stack:
        key, value = stack.pop()
        if isinstance(value, (DictConfig, ListConfig)):
            value = OmegaConf.to_container(value, resolve=resolve)
        if isinstance(value, dict):
            yield key, value
            stack.extend((f"{key}.{k}", v) for k, v in value.items() if k != "_target_")
        elif isinstance(value, list):
            stack.extend((f"{key}[{i}]", v) for i, v in enumerate(value))


def check_targets(node: Any, where: str, source: str | None = None) -> None:
    """Refuse, in one line, a ``_target_`` anywhere in ``node`` that is not a registered option's
    (:func:`registered_targets`): a config read from a checkpoint, run dir or bank is data, and
    may only select what the project's and the user's own options build. ``where``: the node's
    key (``traj``); ``source``: the file it was read from, named in the error."""
    for key, value in _dict_nodes(node, where, resolve=False):
        if "_target_" not in value:
            continue
        target = value["_target_"]
        if not isinstance(target, str) or target not in registered_targets():
            origin = f" (read from {source})" if source else ""
            raise ConfigError(
                f"{key}._target_: {target!r} is not the target of any config option{origin}; "
                "a config may only build what an option of the config tree or your --config-dir names"
            )


def check_target_args(node: Any, where: str) -> None:
    """Every ``_target_`` in ``node`` registered (:func:`check_targets`) and its arguments inside
    the ranges its class declares (``ARG_RANGES``): one ConfigError naming the key, before
    anything is built. Arguments that are themselves nodes (nested options) are checked in turn."""
    from hydra.utils import get_object

    check_targets(node, where)
    for key, value in _dict_nodes(node, where, resolve=True):
        target = value.get("_target_")
        if isinstance(target, str):
            try:
                built = get_object(target)
            except Exception as exc:  # Hydra reports a missing module as a bare Exception
                raise ConfigError(f"{key}._target_: {target!r} cannot be imported ({one_line(exc)})") from None
            if isinstance(built, type):
                literal = {
                    k: v
                    for k, v in value.items()
                    if not k.startswith("_") and not (isinstance(v, dict) and "_target_" in v)
                }
                check_arg_ranges(built, literal, key)


def instantiate_option(cfg: DictConfig, group: str) -> Any:
    """``hydra.utils.instantiate(cfg[group])`` with errors reduced to one line naming the group.
    Only registered targets are built (:func:`check_targets`)."""
    from hydra.utils import instantiate

    node = cfg.get(group)
    if node is None:
        raise ConfigError(f"{group}: missing; choose one of {', '.join(available_options(group))}")
    check_targets(node, group)
    try:
        return instantiate(node, _convert_="all")
    except Exception as exc:  # Hydra wraps constructor errors in InstantiationException
        msg = one_line(exc)
        raise ConfigError(msg if msg.startswith(f"{group}.") else f"{group}: {msg}") from None


_MISSING_OPTION = re.compile(r"Could not find '([^'/]+)/([^']+)'")
_BAD_OVERRIDE = re.compile(r"Could not override '([^']+)'")


def hydra_error_to_config_error(exc: BaseException) -> ConfigError:
    """Turn Hydra's multi-line composition errors into one line naming key and allowed values."""
    text = str(exc)
    m = _MISSING_OPTION.search(text)
    if m:
        group, name = m.groups()
        return ConfigError(f"{group}: unknown option {name!r}; allowed: {', '.join(available_options(group))}")
    m = _BAD_OVERRIDE.search(text)
    if m:
        key = m.group(1)
        return ConfigError(f"{key}: no such key ({one_line(exc)}); to add a new key use +{key}=...")
    return ConfigError(one_line(exc))


def compose(config_name: str = "sim", overrides: list[str] | None = None) -> DictConfig:
    """Compose ``datt/conf/<config_name>.yaml`` with Hydra overrides, outside ``@hydra.main``
    (tests, benchmarks, notebooks)."""
    from hydra import compose as hydra_compose
    from hydra import initialize_config_module
    from hydra.core.global_hydra import GlobalHydra
    from hydra.errors import HydraException

    GlobalHydra.instance().clear()
    try:
        with initialize_config_module(config_module=CONF_PACKAGE, version_base="1.3"):
            return hydra_compose(config_name=config_name, overrides=list(overrides or []))
    except (HydraException, OmegaConfBaseException) as exc:
        raise hydra_error_to_config_error(exc) from None


def hydra_choice(group: str, default: str = "custom") -> str:
    """The option name Hydra chose for ``group`` in the running job (for labels)."""
    try:
        from hydra.core.hydra_config import HydraConfig

        return str(HydraConfig.get().runtime.choices.get(group, default))
    except ValueError:  # not inside a Hydra job
        return default
