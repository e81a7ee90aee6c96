"""Shell completion (flatcli/completion.py): the --set keys and words it offers are the
schema's, and a Tab answers without loading the numerical libraries."""

from __future__ import annotations

import os
import subprocess
import sys

from flatcli.completion import robot_names, set_items, set_words
from flatcli.spec import SCHEMA, all_keys
from flatcli.spec.compose import robot_names as shipped_robots

HEAVY = ("numpy", "numba", "scipy", "pandas", "pyarrow", "matplotlib")


def test_the_keys_and_words_offered_are_the_schemas() -> None:
    """Every key, in the schema's order; a choice's words its choices (the core's
    enumerations for those the core defines), a flag's true and false."""
    assert list(set_words()) == all_keys()
    assert set_words()["plant.model"] == ("kinematic", "dynamic")
    assert set_words()["track.integrator"] == ("adaptive", "rk4", "dop853")
    assert set_words()["task.rest"] == ("true", "false")
    assert set_words()["track.dt"] == ()
    for section, keys in SCHEMA.items():
        for name, key in keys.items():
            dotted = f"{section}.{name}" if section else name
            assert set(set_words()[dotted]) == (set(key.choices or ()) if key.kind == "choice"
                                                else {"true", "false"} if key.kind == "bool"
                                                else set())
    assert robot_names() == shipped_robots()


def test_a_key_completes_to_key_equals_and_then_to_its_words() -> None:
    assert [v for v, _ in set_items("track.k")] == ["track.kp=", "track.kv="]
    assert [v for v, _ in set_items("plant.model=d")] == ["plant.model=dynamic"]
    assert [v for v, _ in set_items("robot=ch")] == ["robot=chain4", "robot=chain6"]
    assert set_items("track.dt=") == []  # a number: nothing to offer
    assert set_items("nothing.") == []


def _complete(words: str) -> tuple[str, str]:
    code = ("import sys\n"
            "from flatcli.cli import main\n"
            "try:\n"
            "    main()\n"
            "except SystemExit:\n"
            "    pass\n"
            f"print(sorted(m for m in {HEAVY!r} if m in sys.modules), file=sys.stderr)\n")
    env = {**os.environ, "_FLATCLI_COMPLETE": "bash_complete", "COMP_WORDS": words,
           "COMP_CWORD": str(len(words.split()) - 1)}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True, env=env)
    return done.stdout, done.stderr.strip().splitlines()[-1]


def test_the_shell_completes_set_and_robot_at_once() -> None:
    out, loaded = _complete("flatcli track --set plant.serv")
    assert "plant.servo_bandwidth=" in out and "plant.servo_model=" in out
    assert loaded == "[]"
    out, loaded = _complete("flatcli plan --robot ch")
    assert "chain4" in out and "chain6" in out and loaded == "[]"
