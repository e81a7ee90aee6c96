"""Experiment specs: TOML in, validated immutable records out; ``--set`` overrides in one place.

A spec is a TOML file with the tables ``[robot]``, ``[plan]``, ``[plan.optimize]``,
``[track]``, ``[plant]`` and, for a sweep, ``[sweep]``; every key has a default (the paper's
example), so an empty spec is the paper.

* ``keys``: one key's kind, default, unit and bounds, and the one check of its values;
* ``schema``: the section records (one line per key) and the ``Spec`` that holds them;
* ``sweeps``: the rules of ``[sweep.perturb]`` and ``[sweep.grid]``;
* ``build``: TOML and ``--set`` items to a validated ``Spec``;
* ``tree``: spec files read, trees and their dotted keys (every such walk, once);
* ``toml``: a spec back as TOML; ``markdown``: the spec tables of docs/spec.md;
  ``compose``: robot files and includes.
"""

from flatcli.spec.build import Spec, build, load_spec, parse_set, resolve
from flatcli.spec.keys import Key, SpecError
from flatcli.spec.schema import (
    GAINS,
    LINKS,
    SCHEMA,
    SECTIONS,
    OptimizeSpec,
    PlanSpec,
    PlantSpec,
    RobotSpec,
    SweepSpec,
    TrackSpec,
    all_keys,
    check_value,
    find_key,
    lookup,
)
from flatcli.spec.sweeps import (
    PERTURB_TARGETS,
    Perturbation,
    grid_overrides,
    perturbation,
    perturbations,
)
from flatcli.spec.toml import spec_toml
from flatcli.spec.tree import read_toml

__all__ = [
    "GAINS",
    "LINKS",
    "PERTURB_TARGETS",
    "SCHEMA",
    "SECTIONS",
    "Key",
    "OptimizeSpec",
    "Perturbation",
    "PlanSpec",
    "PlantSpec",
    "RobotSpec",
    "Spec",
    "SpecError",
    "SweepSpec",
    "TrackSpec",
    "all_keys",
    "build",
    "check_value",
    "find_key",
    "grid_overrides",
    "load_spec",
    "lookup",
    "parse_set",
    "perturbation",
    "perturbations",
    "read_toml",
    "resolve",
    "spec_toml",
]
