"""The campaign file: a scenario, a grid of overrides, seeds; validated once, errors that name the field.

```yaml
scenario: coverage.yaml                 # relative to this file
set: {duration: 40}                     # overrides of every run (any `mrswarm run --set` key)
grid:                                   # every combination is a cell
  fleet.count: [3, 5]
  network.netem.preset: [none, lte]
seeds: 3                                # seeds 0, 1, 2 (the scenario's `seed`), or a list: [7, 11]
metrics: [coverage.time_to_90_s, rtf.mean, cpu_cores]   # the plots (default: by mission type)
```

:func:`load_campaign` validates the file (``campaign.yaml: grid.fleet.count: ...``), then the
scenario of every cell (``campaign.yaml: grid.fleet.count = 0: scenarios/coverage.yaml:
fleet.count: ...``), so a bad grid value is refused before anything flies. A cell's scenario is
loaded from exactly the ``--set`` texts its runs are given (:attr:`Slot.overrides`), so what was
validated is what flies.

A run's place is its *slot*: a cell and a seed, with a folder of its own under the campaign
folder (:mod:`mrswarm.sweep.slots`); its key is a digest of the scenario it flies, once resolved
(:attr:`Slot.digest`), so a campaign folder whose scenario, fixed overrides or a cell's values
changed is noticed rather than mixed.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import msgspec
import yaml
from msgspec import Meta

from groundfloor.errors import MrswarmError
from groundfloor.schema import Config, ConfigError, convert, to_builtins
from mrswarm.scenario import Scenario, ScenarioError, load_scenario, read_scenario_text

MAX_SEEDS = 1000
MAX_SLOTS = 10_000
KEY_RE = r"^[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z0-9_]+)*$"  # a --set key: fleet.count, uavs.1.rtf
NAME_RE = r"^[A-Za-z0-9_\-]{1,64}$"



class CampaignError(ValueError, MrswarmError):
    """A campaign that cannot be flown; the message names the file and the field."""


class Campaign(Config, kw_only=True, frozen=True):
    """A campaign file (docs/campaigns.md, "The campaign file")."""

    scenario: Annotated[str, Meta(min_length=1)]  # relative to the campaign file
    name: Annotated[str, Meta(pattern=NAME_RE)] | None = None  # default: the file's name without .yaml
    description: str = ""
    fixed: dict[str, Any] = msgspec.field(default_factory=dict, name="set")  # every run's overrides
    grid: dict[str, Annotated[list[Any], Meta(min_length=1)]] = msgspec.field(default_factory=dict)
    seeds: Annotated[int, Meta(ge=1, le=MAX_SEEDS)] | Annotated[list[Annotated[int, Meta(ge=0)]], Meta(min_length=1)] = 1
    metrics: list[Annotated[str, Meta(min_length=1)]] | None = None  # what the plots show; default: by mission type
    x: str | None = None  # the plots' horizontal axis: a grid key (default: the first numeric one)
    confidence: Annotated[float, Meta(gt=0.5, lt=1.0)] = 0.95
    # runs at once: N at most, or auto (as many as fit); default 1 on this machine, auto on a swarm
    parallel: Annotated[int, Meta(ge=1, le=64)] | Literal["auto"] | None = None
    record: bool = True  # each run's flight recording (run.mcap)

    def __post_init__(self) -> None:
        for where, keys in (("set", self.fixed), ("grid", self.grid)):
            if "seed" in keys:
                raise ConfigError(f"{where}.seed", "the seeds come from `seeds` (a count, or a list such as [7])")
        both = sorted(set(self.fixed) & set(self.grid))
        if both:
            raise ConfigError(f"grid.{both[0]}", "also in `set`: a key is either fixed or swept")
        for key, values in self.grid.items():
            labels = [value_label(v) for v in values]
            dup = sorted({v for v in labels if labels.count(v) > 1})
            if dup:
                raise ConfigError(f"grid.{key}", f"the value {dup[0]} is listed twice")
        if self.x is not None and self.x not in self.grid:
            raise ConfigError("x", f"{self.x} is not a grid key (there: {', '.join(self.grid) or 'none'})")
        if isinstance(self.seeds, list) and len(set(self.seeds)) != len(self.seeds):
            raise ConfigError("seeds", "a seed is listed twice")

    @property
    def seed_list(self) -> list[int]:
        return list(range(self.seeds)) if isinstance(self.seeds, int) else list(self.seeds)


@dataclass(frozen=True)
class Cell:
    """One combination of the grid's values."""

    index: int
    values: dict[str, Any]  # grid key -> value

    @property
    def slug(self) -> str:
        """A folder name: ``count-5_preset-lte`` (a short digest when the values do not spell safely)."""
        if not self.values:
            return "all"
        parts, lossy = [], False
        tails = [k.rsplit(".", 1)[-1] for k in self.values]
        for key, value in self.values.items():
            tail = key.rsplit(".", 1)[-1]
            name = tail if tails.count(tail) == 1 else key
            label = value_label(value)
            safe = re.sub(r"[^A-Za-z0-9.+\-]+", "-", label).strip("-") or "x"
            lossy = lossy or safe != label
            parts.append(f"{name}-{safe}")
        slug = "_".join(parts)
        if lossy or len(slug) > 100:
            digest = hashlib.sha256(json.dumps(self.values, sort_keys=True).encode()).hexdigest()[:6]
            slug = f"{slug[:90]}-{digest}"
        return slug

    @property
    def label(self) -> str:
        """``fleet.count=5 network.netem.preset=lte``."""
        return " ".join(f"{k}={value_label(v)}" for k, v in self.values.items()) or "(no grid)"


@dataclass(frozen=True)
class Slot:
    """A cell at one seed: one run of the campaign."""

    cell: Cell
    seed: int
    overrides: tuple[str, ...]  # the --set texts, fixed ones first, then the cell's, then the seed
    digest: str  # of the resolved scenario
    scenario: Scenario

    @property
    def name(self) -> str:
        return f"{self.cell.slug}_seed-{self.seed}"

    @property
    def label(self) -> str:
        return f"{self.cell.label} seed={self.seed}"


@dataclass(frozen=True)
class Plan:
    """A validated campaign: where it came from, its cells and its slots in flying order."""

    campaign: Campaign
    source: Path | None  # the campaign file (None: from flags)
    scenario_path: Path
    name: str
    cells: list[Cell]
    slots: list[Slot]
    notes: list[str]  # what load_scenario said (a shortened schedule), once per distinct sentence

    @property
    def grid_keys(self) -> list[str]:
        return list(self.campaign.grid)


def value_label(value: Any) -> str:
    """A grid value as a word: ``5``, ``lte``, ``none`` for null, JSON for a mapping or list."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float | str):
        return str(value)
    return json.dumps(value, sort_keys=True, separators=(",", ":"))


def override_text(key: str, value: Any) -> str:
    """``key=value`` as ``mrswarm run --set`` reads it back (the value as JSON, which YAML reads as the same value)."""
    return f"{key}={json.dumps(value, ensure_ascii=False)}"


def parse_campaign(data: Any, where: str) -> Campaign:
    if not isinstance(data, dict):
        raise CampaignError(f"{where}: a campaign must be a YAML mapping, got {type(data).__name__}")
    for section in ("set", "grid"):
        if isinstance(data.get(section), dict):
            for key in data[section]:
                if not isinstance(key, str) or not re.match(KEY_RE, key):
                    raise CampaignError(f"{where}: {section}: {key!r} is not a scenario field's key (dotted names, as "
                                        "`mrswarm run --set` takes them: fleet.count, uavs.1.rtf)")
    try:
        return convert(data, Campaign)
    except ConfigError as exc:
        raise CampaignError(f"{where}: {exc}") from None


def read_campaign(path: Path) -> Campaign:
    text = _read_text(path)
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        at = f":{mark.line + 1}:{mark.column + 1}" if mark else ""
        raise CampaignError(f"{path}{at}: not valid YAML: {getattr(exc, 'problem', exc)}") from None
    return parse_campaign(data, str(path))


def is_campaign_file(path: Path) -> bool:
    """A campaign names a ``scenario``; a scenario file does not (it has a ``mission``)."""
    try:
        data = yaml.safe_load(_read_text(path))
    except (CampaignError, yaml.YAMLError):
        return False
    return isinstance(data, dict) and "scenario" in data and "mission" not in data


def _read_text(path: Path) -> str:
    try:
        return read_scenario_text(path)  # the same limits as a scenario: a regular UTF-8 file of at most 1 MB
    except ScenarioError as exc:
        raise CampaignError(str(exc).replace("a scenario", "a campaign")) from None


def plan_campaign(campaign: Campaign, source: Path | None, where: str | None = None) -> Plan:
    """Every cell's scenario validated; the slots in flying order: every cell at the first seed, then at the
    second, and so on, so that an interrupted campaign has its runs spread over the cells."""
    where = where or (str(source) if source is not None else "sweep")
    base = source.parent if source is not None else Path(".")
    scenario_path = Path(os.path.normpath(base / campaign.scenario))  # campaigns/../scenarios/x.yaml: scenarios/x.yaml
    if not scenario_path.is_file():
        raise CampaignError(f"{where}: scenario: {scenario_path}: no such file")
    keys = list(campaign.grid)
    cells = [Cell(i, dict(zip(keys, combo, strict=True)))
             for i, combo in enumerate(itertools.product(*(campaign.grid[k] for k in keys)))]
    seeds = campaign.seed_list
    if len(cells) * len(seeds) > MAX_SLOTS:
        raise CampaignError(f"{where}: grid: {len(cells)} cells x {len(seeds)} seeds = {len(cells) * len(seeds):,} runs; "
                            f"at most {MAX_SLOTS:,}")
    fixed = [override_text(k, v) for k, v in campaign.fixed.items()]
    by_cell: dict[int, list[str]] = {c.index: [override_text(k, v) for k, v in c.values.items()] for c in cells}
    slots: list[Slot] = []
    notes: list[str] = []
    for seed in seeds:
        for cell in cells:
            overrides = (*fixed, *by_cell[cell.index], f"seed={seed}")
            said: list[str] = []
            try:
                scn = load_scenario(scenario_path, list(overrides), said)
            except ScenarioError as exc:
                raise CampaignError(f"{where}: {_blame(campaign, cell, str(exc))}{exc}") from None
            notes += [n for n in said if n not in notes]
            slots.append(Slot(cell=cell, seed=seed, overrides=overrides, digest=scenario_digest(scn), scenario=scn))
    if campaign.name is not None:
        name = campaign.name
    elif source is not None:
        name = re.sub(r"[^A-Za-z0-9_\-]+", "-", source.stem)[:64] or "campaign"
    else:
        name = slots[0].scenario.name
    return Plan(campaign=campaign, source=source, scenario_path=scenario_path, name=name, cells=cells, slots=slots, notes=notes)


def _blame(campaign: Campaign, cell: Cell, error: str) -> str:
    """Which part of the campaign a scenario error comes from: the grid values or fixed overrides whose key the error
    names (``grid.fleet.count = 0: ``), else every value of the cell (a rule between fields), else nothing (the
    scenario itself)."""
    def named(key: str) -> bool:  # the error's field is the key, lies inside it, or is a section holding it
        parts = key.split(".")
        fields = [".".join(parts[:i]) for i in range(len(parts), 1, -1)] or [key]
        return any(re.search(rf"(^|: ){re.escape(f)}(\.|:)", error) for f in fields) or f"--set {key}" in error

    hit = [f"grid.{k} = {value_label(v)}" for k, v in cell.values.items() if named(k)]
    hit += [f"set.{k} = {value_label(v)}" for k, v in campaign.fixed.items() if named(k)]
    if not hit:
        hit = [f"grid.{k} = {value_label(v)}" for k, v in cell.values.items()]
    return ", ".join(hit) + ": " if hit else ""


def scenario_digest(scn: Scenario) -> str:
    """A digest of the resolved scenario: two slots fly the same experiment exactly when theirs are equal."""
    return hashlib.sha256(json.dumps(to_builtins(scn), sort_keys=True).encode()).hexdigest()[:16]


def campaign_from_flags(scenario: str, grid: list[str], seeds: int | list[int] | None, sets: list[str]) -> dict[str, Any]:
    """A campaign mapping from ``mrswarm sweep SCENARIO --grid key=v1,v2 --seeds N --set key=value``."""
    data: dict[str, Any] = {"scenario": scenario}
    merge_flags(data, grid, seeds, sets)
    return data


def merge_flags(data: dict[str, Any], grid: list[str], seeds: int | list[int] | None, sets: list[str]) -> None:
    """Flags on top of a campaign file's mapping: ``--grid`` adds or replaces a key, ``--set`` a fixed
    override, ``--seeds`` replaces the seeds."""
    from mrswarm.scenario import parse_override

    for text in grid:
        key, values = parse_grid(text)
        data.setdefault("grid", {})
        data["grid"][key] = values
        if isinstance(data.get("set"), dict):
            data["set"].pop(key, None)
    for text in sets:
        try:
            key, value = parse_override(text)
        except ScenarioError as exc:
            raise CampaignError(str(exc)) from None
        data.setdefault("set", {})
        data["set"][key] = value
        if isinstance(data.get("grid"), dict):
            data["grid"].pop(key, None)
    if seeds is not None:
        data["seeds"] = seeds


def parse_grid(text: str) -> tuple[str, list[Any]]:
    """``fleet.count=3,5,10`` or ``fleet.count=[3, 5, 10]`` -> ``("fleet.count", [3, 5, 10])``."""
    if "=" not in text:
        raise CampaignError(f"--grid {text!r}: expected key.path=value1,value2,...")
    key, raw = (s.strip() for s in text.split("=", 1))
    try:
        whole = yaml.safe_load(raw)
        values = whole if isinstance(whole, list) else [yaml.safe_load(v) for v in raw.split(",")]
    except yaml.YAMLError as exc:
        raise CampaignError(f"--grid {text!r}: bad value: {exc}") from None
    if not values:
        raise CampaignError(f"--grid {text!r}: no values")
    return key, values


def parse_seeds(text: str) -> int | list[int]:
    """``--seeds 5`` (seeds 0..4) or ``--seeds 7,11,13``."""
    try:
        if "," in text:
            return [int(s) for s in text.split(",") if s.strip()]
        return int(text)
    except ValueError:
        raise CampaignError(f"--seeds {text!r}: a count (5) or a list of seeds (7,11,13)") from None


def campaign_yaml(plan: Plan) -> str:
    """The campaign as flown (the copy in the campaign folder), with its name and its scenario's path made absolute."""
    data = to_builtins(plan.campaign)
    data["scenario"] = str(plan.scenario_path.resolve())
    data["name"] = plan.name
    return yaml.safe_dump(data, sort_keys=False)
