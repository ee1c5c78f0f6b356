"""Mutation testing: how many deliberate small faults in a module its focused tests catch.

    python3 bench/mutation.py [MODULE ...] [--functions F,...] [--sample N] [--seed S]
                              [--keep DIR] [--json FILE]

MODULE is a key of bench/mutation.toml (``runtime/master/recovery.py``), a unique part of one
(``recovery``), or nothing for every module there.  For each module, in a temporary copy of
the checkout (git's tracked and untracked-but-not-ignored files; the working tree is never
mutated), mutmut (the ``mutation`` extra of pyproject.toml) makes the mutants of that module
alone, runs the module's focused tests once to learn which test calls which function, then
each mutant against the tests that call its function, one at a time under ``nice -n 19``.

Per module it prints the mutants made, how many were tested (all, or a seeded sample of
``--sample N``), and of those: killed, survived, timeout, no tests (no focused test calls the
function), other (mutmut's "suspicious", "segfault", ...) and the score, (killed + timeout) /
tested.  ``--functions F,...`` keeps only the mutants of those functions or methods (by
name, ``_compile,copy_slave_to_slave``) before the sample is drawn: part of a module.
``--json FILE`` writes the same with the names of the survivors; ``--keep DIR``
keeps each module's copy as DIR/<module>, where ``mutmut show NAME`` prints a survivor's
diff and ``mutmut results`` lists them all (docs/BENCHMARKS.md, "Mutation testing").

The tests read the corpus from ECATCFG_CORPUS / ECATCFG_CORPUS_EXTRA, by default the
checkout's (the copy has none beside it); where it is missing the corpus tests skip, and
mutants only they would kill survive.  With CI=true they fail instead, and mutmut refuses to
start: a module's focused tests must pass on the unmutated copy.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import random
import shutil
import subprocess
import sys
import tempfile
import time
import tomllib
from dataclasses import asdict, dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CONFIG = Path(__file__).resolve().with_suffix(".toml")
# The import name: the checkout is the package (pyproject.toml, package-dir), so the copy
# puts it in a folder of that name.
PACKAGE = "ecatcfg"
# A pattern no mutant name matches: mutmut then makes the mutants and collects which tests
# call which function, and stops before testing any, so that a sample can be drawn.
NO_MUTANT = "no-mutant-matches-this"
# How long a mutant may run, from its tests' clean time t: (t + constant) * multiplier seconds
# (mutmut's timeout_constant / timeout_multiplier).  Smaller than mutmut's default (15x), so
# that a mutant that makes a wait never end costs minutes, not an hour; large enough for a
# 2-core machine shared with other work.
TIMEOUT_CONSTANT = 5.0
TIMEOUT_MULTIPLIER = 5.0


@dataclass
class Result:
    module: str
    mutants: int = 0
    tested: int = 0
    killed: int = 0
    survived: int = 0
    timeout: int = 0
    no_tests: int = 0
    other: int = 0
    seconds: float = 0.0
    sample_seed: int | None = None
    survivors: list[str] = field(default_factory=list)
    untested: list[str] = field(default_factory=list)

    @property
    def score(self) -> float:
        return (self.killed + self.timeout) / self.tested if self.tested else 0.0


@dataclass
class Focus:
    """A module's focused tests (bench/mutation.toml): files, and pytest arguments that
    leave out what a loaded machine would fail on the unmutated code."""

    tests: list[str]
    pytest_args: list[str] = field(default_factory=list)


def load_config(path: Path = CONFIG) -> dict[str, Focus]:
    """Module -> its focused tests, from bench/mutation.toml."""
    raw = tomllib.loads(path.read_text(encoding="utf-8"))
    return {module: Focus(list(entry["tests"]), list(entry.get("pytest_args", [])))
            for module, entry in raw["modules"].items()}


def select(config: dict[str, Focus], wanted: list[str]) -> list[str]:
    if not wanted:
        return list(config)
    chosen = []
    for want in wanted:
        hits = [m for m in config if m == want] or [m for m in config if want in m]
        if len(hits) != 1:
            raise SystemExit(f"mutation.py: {want!r} names {len(hits)} modules of {CONFIG.name}: "
                             f"{', '.join(hits or config)}")
        chosen.append(hits[0])
    return chosen


def copy_checkout(dest: Path) -> None:
    """The checkout's files as git sees them (tracked, and new files not ignored), without
    symlinks (.mypy_path/ecatcfg points at the checkout itself)."""
    listed = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
                            cwd=ROOT, check=True, capture_output=True).stdout
    for name in filter(None, listed.decode().split("\0")):
        source = ROOT / name
        if source.is_symlink() or not source.is_file():
            continue                              # a symlink, or a file deleted but not staged
        target = dest / name
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(source, target)


def _toml_list(items: list[str]) -> str:
    return "[" + ", ".join(json.dumps(i) for i in items) + "]"


def write_mutmut_config(work: Path, module: str, focus: Focus) -> None:
    # mutmut reads [tool.mutmut] of the pyproject.toml in its working folder; the package's
    # own pyproject.toml (pytest's settings) stays in the package folder.
    (work / "pyproject.toml").write_text(
        "[tool.mutmut]\n"
        f"source_paths = {_toml_list([PACKAGE])}\n"
        f"only_mutate = {_toml_list([f'{PACKAGE}/{module}'])}\n"
        f"also_copy = {_toml_list([PACKAGE])}\n"
        "pytest_add_cli_args_test_selection = "
        f"{_toml_list([f'{PACKAGE}/{t}' for t in focus.tests])}\n"
        f"pytest_add_cli_args = {_toml_list(['-p', 'no:cacheprovider', *focus.pytest_args])}\n"
        f"timeout_constant = {TIMEOUT_CONSTANT}\n"
        f"timeout_multiplier = {TIMEOUT_MULTIPLIER}\n",
        encoding="utf-8")


def _environment(work: Path) -> dict[str, str]:
    env = dict(os.environ)
    # mutmut puts the mutated copy (work/mutants) first on the tests' own sys.path.  What the
    # tests start as a new process (`python -m ecatcfg simulate`) runs elsewhere, where
    # mutmut's trampolines cannot find their configuration: it imports the unmutated copy,
    # not the installed ecatcfg.  So only code that runs in the test process is mutated.
    # The copy has no corpus beside it: the tests look where the checkout's would (conftest).
    env.setdefault("ECATCFG_CORPUS", str(ROOT.parent / "shared" / "corpus"))
    env.setdefault("ECATCFG_CORPUS_EXTRA", str(ROOT.parent / "shared" / "corpus-extra"))
    env["PYTHONPATH"] = os.pathsep.join([str(work)]
                                        + [p for p in [env.get("PYTHONPATH", "")] if p])
    return env


def _mutmut(work: Path, args: list[str], log: Path) -> int:
    with log.open("ab") as out:
        return subprocess.run(["nice", "-n", "19", sys.executable, "-m", "mutmut", *args],
                              cwd=work, env=_environment(work), stdout=out,
                              stderr=subprocess.STDOUT).returncode


def _exit_codes(work: Path, module: str) -> dict[str, int | None]:
    meta = work / "mutants" / PACKAGE / f"{module}.meta"
    if not meta.is_file():
        return {}
    codes: dict[str, int | None] = json.loads(meta.read_text(encoding="utf-8"))["exit_code_by_key"]
    return codes


class Failed(Exception):
    """mutmut could not test the module (its log says why)."""


def function_of(mutant: str) -> str:
    """The function or method a mutant's name belongs to: mutmut names a mutant
    ``<module>.x_<function>__mutmut_<n>``, or ``<module>.xǁ<class>ǁ<method>__mutmut_<n>``."""
    stem = mutant.rsplit("__mutmut_", 1)[0].rsplit(".", 1)[-1]
    return stem.rsplit("ǁ", 1)[-1] if "ǁ" in stem else stem.removeprefix("x_")


def run_module(module: str, focus: Focus, work: Path, sample: int | None,
               seed: int, functions: list[str] | None = None) -> Result:
    from mutmut.stats import status_by_exit_code  # the tool's own reading of its exit codes

    started = time.monotonic()
    copy_checkout(work / PACKAGE)
    write_mutmut_config(work, module, focus)
    log = work / "mutmut.log"
    _mutmut(work, ["run", "--max-children", "1", NO_MUTANT], log)
    names = sorted(_exit_codes(work, module))
    if not names:
        raise Failed("mutmut made no mutants (the clean run of its tests failed?); the end of "
                     f"its log:\n{_tail(log)}")
    if functions:
        names = [n for n in names if function_of(n) in functions]
        if not names:
            raise Failed(f"no mutant of {module} is in {', '.join(functions)}")
    chosen = names
    if sample is not None and sample < len(names):
        chosen = sorted(random.Random(seed).sample(names, sample))
    code = _mutmut(work, ["run", "--max-children", "1", *chosen], log)
    if code != 0:
        raise Failed(f"mutmut failed (exit {code}); the end of its log:\n{_tail(log)}")
    codes = _exit_codes(work, module)
    result = Result(module, mutants=len(names), tested=len(chosen),
                    sample_seed=seed if chosen is not names else None)
    for name in chosen:
        status = status_by_exit_code[codes.get(name)]
        if status == "killed":
            result.killed += 1
        elif status == "survived":
            result.survived += 1
            result.survivors.append(name)
        elif status == "timeout":
            result.timeout += 1
        elif status == "no tests":
            result.no_tests += 1
            result.untested.append(name)
        else:
            result.other += 1
    result.seconds = round(time.monotonic() - started, 1)
    return result


def _tail(log: Path, lines: int = 25) -> str:
    """The last lines of mutmut's log: the folder it is in goes when the run ends."""
    text = log.read_text(errors="replace") if log.exists() else "(no log)"
    return "\n".join("    " + line for line in text.splitlines()[-lines:])


def _slug(module: str) -> str:
    return module.removesuffix(".py").replace("/", ".")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("modules", nargs="*", help="keys of bench/mutation.toml (default: all)")
    parser.add_argument("--functions", type=lambda v: [f for f in v.split(",") if f],
                        help="only the mutants of these functions or methods, comma-separated")
    parser.add_argument("--sample", type=int, help="test N mutants per module, drawn at random")
    parser.add_argument("--seed", type=int, default=1, help="seed of the sample (default 1)")
    parser.add_argument("--keep", type=Path, help="keep each module's copy in DIR/<module>")
    parser.add_argument("--json", type=Path, help="write the results, survivors named, here")
    args = parser.parse_args(argv)

    config = load_config()
    modules = select(config, args.modules)
    results: list[Result] = []
    print(f"{'module':24} {'mutants':>7} {'tested':>6} {'killed':>6} {'survived':>8} "
          f"{'timeout':>7} {'no tests':>8} {'other':>5} {'score':>6} {'s':>6}")
    failed: dict[str, str] = {}
    for module in modules:
        with tempfile.TemporaryDirectory(prefix="ecatcfg-mutation-") as tmp:
            work = Path(tmp)
            if args.keep is not None:
                work = args.keep.resolve() / _slug(module)
                if work.exists():
                    shutil.rmtree(work)
                work.mkdir(parents=True)
            try:
                r = run_module(module, config[module], work, args.sample, args.seed,
                               args.functions)
            except Failed as exc:
                failed[module] = str(exc)
                print(f"{module:24} not tested: {exc}", flush=True)
                continue
        results.append(r)
        sampled = f" (sample, seed {r.sample_seed})" if r.sample_seed is not None else ""
        print(f"{module:24} {r.mutants:7} {r.tested:6} {r.killed:6} {r.survived:8} "
              f"{r.timeout:7} {r.no_tests:8} {r.other:5} {r.score:6.1%} {r.seconds:6.0f}{sampled}",
              flush=True)
        if args.json is not None:                 # after each module: a long run may be cut
            _write_json(args.json, results, failed)
    if args.json is not None:
        _write_json(args.json, results, failed)
    return 1 if failed else 0


def _write_json(path: Path, results: list[Result], failed: dict[str, str]) -> None:
    path.write_text(json.dumps({
        "machine": f"{platform.machine()}, {os.cpu_count()} CPUs, "
                   f"Python {platform.python_version()}",
        "date": time.strftime("%Y-%m-%d"),
        "modules": [asdict(r) | {"score": round(r.score, 4)} for r in results],
        "not_tested": failed,
    }, indent=2) + "\n", encoding="utf-8")


if __name__ == "__main__":
    raise SystemExit(main())
