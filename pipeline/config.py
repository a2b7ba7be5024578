"""Layered config: stage defaults <- configs/default.yaml <- --config files <- --set key=value.

Every error is one line naming the key and what is valid.
"""

from __future__ import annotations

import copy
import typing
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, ValidationError

import endopipe
from endopipe.pipeline.errors import ConfigError
from endopipe.pipeline.stage import Stage, StageConfig

#: Presets ship inside the installed package (endopipe/configs), so a wheel has them too.
CONFIG_DIR = Path(endopipe.__file__).resolve().parent / "configs"
#: Files in configs/ that are not stage presets (cluster settings for `endopipe batch`).
NOT_PRESETS = {"cluster"}


def preset_names() -> list[str]:
    return sorted(f.stem for f in CONFIG_DIR.glob("*.yaml") if f.stem not in NOT_PRESETS)


def resolve_config_path(name_or_path: str) -> Path:
    """A path, or the name of a preset in configs/ (`fast` -> configs/fast.yaml)."""
    p = Path(name_or_path)
    if p.is_file():
        return p
    name = name_or_path.removesuffix(".yaml")
    if name in preset_names():
        return CONFIG_DIR / f"{name}.yaml"
    presets = ", ".join(preset_names())
    raise ConfigError(f"config file not found: {name_or_path} (presets: {presets})")


def read_yaml(path: Path) -> dict[str, Any]:
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" line {mark.line + 1}" if mark else ""
        raise ConfigError(f"config file {path}{where} is not valid YAML; fix it or drop it") from e
    if not isinstance(data, dict):
        raise ConfigError(f"config file {path} must map stage names to settings")
    return data


def deep_merge(base: dict, over: Mapping) -> dict:
    out = copy.deepcopy(base)
    for k, v in over.items():
        if isinstance(v, Mapping) and isinstance(out.get(k), dict):
            out[k] = deep_merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


def parse_set(item: str) -> tuple[list[str], Any]:
    """`stage.key=value` (value parsed as YAML, so 0.5 is a float and [1,2] a list)."""
    if "=" not in item:
        raise ConfigError(f"--set {item!r} must look like stage.key=value")
    key, raw = item.split("=", 1)
    path = [p for p in key.strip().split(".") if p]
    if len(path) < 2:
        raise ConfigError(f"--set {item!r} must name a stage and a key, e.g. ingest.stride=2")
    try:
        value = yaml.safe_load(raw) if raw.strip() else ""
    except yaml.YAMLError:
        value = raw
    return path, value


def _check_keys(model: type[BaseModel], data: Mapping, prefix: str, origin: str) -> None:
    """Name an unknown key and the valid ones before pydantic gives a less friendly message."""
    fields = model.model_fields
    for k, v in data.items():
        if k not in fields:
            valid = ", ".join(fields) or "(none)"
            raise ConfigError(f"unknown key '{prefix}.{k}' ({origin}); valid keys: {valid}")
        sub = _submodel(fields[k].annotation)
        if sub is not None and isinstance(v, Mapping):
            _check_keys(sub, v, f"{prefix}.{k}", origin)


def _submodel(annotation: Any) -> type[BaseModel] | None:
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    for arg in typing.get_args(annotation):
        if isinstance(arg, type) and issubclass(arg, BaseModel):
            return arg
    return None


def _validation_line(stage: str, err: ValidationError) -> str:
    e = err.errors()[0]
    loc = ".".join(str(p) for p in (stage, *e["loc"]))
    got = e.get("input")
    return f"{loc}: {e['msg']} (got {got!r})"


def load_config(
    stages: Sequence[type[Stage]],
    files: Sequence[str] = (),
    sets: Sequence[str] = (),
    use_default_file: bool = True,
) -> dict[str, StageConfig]:
    by_name = {s.name: s for s in stages}
    layers: list[tuple[str, dict]] = []
    default_file = CONFIG_DIR / "default.yaml"
    if use_default_file and default_file.is_file():
        layers.append((str(default_file), read_yaml(default_file)))
    for f in files:
        path = resolve_config_path(f)
        layers.append((str(path), read_yaml(path)))
    raw: dict[str, dict] = {name: {} for name in by_name}
    for origin, data in layers:
        for stage, settings in data.items():
            _require_stage(stage, by_name, origin)
            if settings is None:
                continue
            if not isinstance(settings, Mapping):
                raise ConfigError(f"'{stage}' in {origin} must map keys to values")
            _check_keys(by_name[stage].Config, settings, stage, origin)
            raw[stage] = deep_merge(raw[stage], settings)
    for item in sets:
        path, value = parse_set(item)
        _require_stage(path[0], by_name, "--set")
        nested: Any = value
        for p in reversed(path[1:]):
            nested = {p: nested}
        _check_keys(by_name[path[0]].Config, nested, path[0], "--set")
        raw[path[0]] = deep_merge(raw[path[0]], nested)
    out: dict[str, StageConfig] = {}
    for name, stage in by_name.items():
        try:
            out[name] = stage.Config.model_validate(raw[name])
        except ValidationError as e:
            raise ConfigError(_validation_line(name, e)) from None
    return out


def _require_stage(name: str, by_name: Mapping, origin: str) -> None:
    if name not in by_name:
        raise ConfigError(f"unknown stage '{name}' ({origin}); stages: {', '.join(by_name)}")


#: In a case folder: the resolved configuration of its last run (`endopipe status` judges
#: against it; it is also a valid --config file, to repeat the run).
RUN_CONFIG = "config.yaml"


def save_run_config(case_dir: Path, configs: Mapping[str, StageConfig]) -> Path:
    """Record what a run was asked to do, written whole (temporary file, then rename)."""
    path = Path(case_dir) / RUN_CONFIG
    data = {name: cfg.model_dump(mode="json") for name, cfg in configs.items()}
    header = (
        "# The resolved configuration of this case's last run (defaults, presets, --set).\n"
        "# `endopipe status` judges against it; `endopipe run --config THIS_FILE` repeats it.\n"
    )
    tmp = path.with_name(f".{RUN_CONFIG}.tmp")
    tmp.write_text(header + yaml.safe_dump(data, sort_keys=False, width=1000))
    tmp.replace(path)
    return path


def load_run_config(stages: Sequence[type[Stage]], case_dir: Path) -> dict[str, StageConfig] | None:
    """The configuration recorded by the case's last run; None when it has none (older runs)."""
    path = Path(case_dir) / RUN_CONFIG
    if not path.is_file():
        return None
    try:
        return load_config(stages, [str(path)], use_default_file=False)  # it is whole
    except ConfigError as e:
        raise ConfigError(
            f"{e}; the last run's configuration no longer loads: pass --config/--set to status, "
            "or re-run the case"
        ) from None


def describe_fields(model: type[BaseModel], prefix: str = "") -> list[tuple[str, str, str, str]]:
    """(key, type, default, help) for every leaf setting, nested groups flattened with dots
    (`train.steps`); defaults as YAML, the form --set and config files take."""
    return _describe(model(), prefix)


def _describe(model: BaseModel, prefix: str) -> list[tuple[str, str, str, str]]:
    rows = []
    for name, field in type(model).model_fields.items():
        value = getattr(model, name)
        if isinstance(value, BaseModel):
            rows.extend(_describe(value, f"{prefix}{name}."))
            continue
        rows.append(
            (
                f"{prefix}{name}",
                _type_name(field.annotation),
                _yaml_value(value),
                field.description or "",
            )
        )
    return rows


def _yaml_value(value: Any) -> str:
    """One value as YAML flow text: `null`, `true`, `[0.15, 0.3]`, `colmap`."""
    dumped = yaml.safe_dump(_jsonable(value), default_flow_style=True, width=1000).strip()
    return dumped.removesuffix("\n...").removesuffix("...").strip()


def _type_name(annotation: Any) -> str:
    origin = typing.get_origin(annotation)
    if origin is typing.Literal:
        return " | ".join(repr(a) for a in typing.get_args(annotation))
    if isinstance(annotation, type):
        return annotation.__name__
    return str(annotation).replace("typing.", "")


def default_yaml(stages: Sequence[type[Stage]]) -> str:
    """configs/default.yaml as the code defines it: every stage, every key, with its help."""
    lines = [
        "# endopipe defaults: every stage's settings with their help and type.",
        "# Generated by `endopipe stages --yaml`; a test checks it matches the code.",
        "# Presets in this folder layer over it: endopipe run INPUT --config fast",
        "",
    ]
    for stage in stages:
        lines.append(f"# {stage.describe()}")
        body = _yaml_lines(stage.Config(), 1)
        lines.append(f"{stage.name}:" if body else f"{stage.name}: {{}}")
        lines.extend(body)
        lines.append("")
    return "\n".join(lines)


def _yaml_lines(model: BaseModel, depth: int) -> list[str]:
    ind = "  " * depth
    out = []
    for name, field in type(model).model_fields.items():
        value = getattr(model, name)
        help_text = field.description or ""
        if isinstance(value, BaseModel):
            out += [f"{ind}# {help_text}", f"{ind}{name}:", *_yaml_lines(value, depth + 1)]
            continue
        dumped = yaml.safe_dump({name: _jsonable(value)}, default_flow_style=True, width=1000)
        out.append(f"{ind}# {help_text} [{_type_name(field.annotation)}]")
        out.append(f"{ind}{dumped.strip()[1:-1]}")
    return out


def _jsonable(value: Any) -> Any:
    if isinstance(value, tuple):
        return list(value)
    if isinstance(value, Path):
        return str(value)
    return value
