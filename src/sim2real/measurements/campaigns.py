"""Campaigns: one measurement session of one arm, a measurement list with the shape of
``configs/{robot}/measurements.yaml`` (``schemas/measurements.schema.yaml``) plus a ``campaign:`` block (``arm``,
``date``). Campaign files live in ``configs/{robot}/campaigns/{campaign}.yaml`` and their reports in
``results/{robot}/{campaign}/``; ``configs/{robot}/measurements.yaml`` itself is the ``default`` campaign, whose
reports keep their paths (``results/{robot}/gap.json``, ``results/{robot}/sysid/``). A campaign is therefore only
a different measurement list and output directory for the same fit and report; the rules build their wildcard
pattern from the names (:func:`wildcard_pattern`), the fleet view (:mod:`sim2real.report.fleet`) reads the same
:class:`Campaign` records.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sim2real.errors import InputError

DEFAULT_CAMPAIGN = "default"


# Names of what results/{robot}/ already holds: a campaign directory may not shadow them.
RESERVED_NAMES = frozenset({
    DEFAULT_CAMPAIGN, "bags", "benchmarks", "calibrated", "collision", "dr", "gap", "lab", "logs", "meshes",
    "mjcf", "sysid", "usd",
})


NAME_PATTERN = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")


DATE_PATTERN = re.compile(r"^\d{4}-\d{2}(-\d{2})?$")


@dataclass(frozen=True)
class Campaign:
    """One measurement session: where its runs are listed and where its reports go."""

    robot: str
    name: str  # DEFAULT_CAMPAIGN or the file stem under configs/{robot}/campaigns/
    measurements: str  # the measurement list (measurements.yaml or the campaign file)
    arm: str  # the physical unit measured (default: the robot's name)
    date: str | None  # YYYY-MM or YYYY-MM-DD; the default campaign may have none

    @property
    def prefix(self) -> str:
        """The ``{campaign}`` wildcard value: "" for the default campaign, else "<name>/"."""
        return campaign_prefix(self.name)

    @property
    def results(self) -> str:
        return f"results/{self.robot}/{self.prefix}"


def campaign_prefix(name: str) -> str:
    return "" if name == DEFAULT_CAMPAIGN else f"{name}/"


def campaign_name(prefix: str) -> str:
    return prefix.rstrip("/") or DEFAULT_CAMPAIGN


def campaign_file(robot: str, name: str, configs: str | Path = "configs") -> str:
    """The measurement list of a campaign (``configs/{robot}/measurements.yaml`` for the default one)."""
    if name == DEFAULT_CAMPAIGN:
        return (Path(configs) / robot / "measurements.yaml").as_posix()
    return (Path(configs) / robot / "campaigns" / f"{name}.yaml").as_posix()


def campaign_names(robot: str, configs: str | Path = "configs") -> list[str]:
    """Names of the robot's campaign files (sorted), each checked to be a usable directory name."""
    folder = Path(configs) / robot / "campaigns"
    names = []
    for path in sorted(folder.glob("*")):
        if path.suffix == ".yml":
            raise InputError(path, None, "campaign files end in .yaml", f"rename it to {path.with_suffix('.yaml').name}")
        if path.suffix != ".yaml":
            continue
        name = path.stem
        if not NAME_PATTERN.match(name):
            raise InputError(path, "file name", f"'{name}' is not a usable campaign name",
                             "use letters, digits, '_', '-' and '.', starting with a letter or digit")
        if name in RESERVED_NAMES:
            raise InputError(path, "file name", f"'{name}' is reserved (results/{robot}/{name} holds other outputs)",
                             f"rename the file, e.g. to {robot}-{name}.yaml")
        names.append(name)
    return names


def _date_text(value: Any) -> Any:
    """YAML reads an unquoted 2026-10-05 as a date: accept it as the ISO text it was meant as."""
    import datetime

    return value.isoformat() if isinstance(value, datetime.date) else value


def load_campaign(robot: str, name: str, configs: str | Path = "configs") -> Campaign:
    """A campaign's metadata from its measurement list (validated by measurements.schema.yaml)."""
    from sim2real.files import read_yaml, validate

    path = campaign_file(robot, name, configs)
    data = read_yaml(path)
    if isinstance(data, dict) and isinstance(data.get("campaign"), dict) and "date" in data["campaign"]:
        data["campaign"]["date"] = _date_text(data["campaign"]["date"])
    validate(data, "measurements.schema.yaml", path)
    block = data.get("campaign") or {}
    date = block.get("date")
    if name != DEFAULT_CAMPAIGN and date is None:
        raise InputError(path, "campaign/date", "a campaign file needs the date it was measured",
                         "add 'campaign: {date: \"2026-10\"}' (YYYY-MM or YYYY-MM-DD)")
    return Campaign(robot=robot, name=name, measurements=path, arm=str(block.get("arm", robot)), date=date)


def robot_campaigns(robot: str, configs: str | Path = "configs") -> list[Campaign]:
    """The default campaign (where measurements.yaml exists) and every campaign file of the robot."""
    names = ([DEFAULT_CAMPAIGN] if Path(campaign_file(robot, DEFAULT_CAMPAIGN, configs)).exists() else [])
    return [load_campaign(robot, name, configs) for name in names + campaign_names(robot, configs)]


def wildcard_pattern(names: Sequence[str]) -> str:
    """Regex of the ``{campaign}`` wildcard: "" (default campaign) or one of ``names`` plus "/"."""
    if not names:
        return "(?:)"  # matches only "" (an empty constraint would fall back to Snakemake's default ".+")
    return "(?:(?:" + "|".join(re.escape(n) for n in sorted(set(names))) + ")/)?"
