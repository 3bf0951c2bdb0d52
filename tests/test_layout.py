"""The layout: seven layers that import downward, the generic ones naming no task, one import root that static tools
resolve, and no shadowing of Hugging Face's `datasets`."""

import ast
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from policy_composer.tasks.registry import TASKS

ROOT = Path(__file__).resolve().parents[1]
# The design card's folders, each a symlink under the one import root.
CARD_FOLDERS = ("tasks", "policies", "selector")
# Each task's own package: it fills in the task's description with what the generic layers give it (the planner, the
# controllers' bases) and sits above them; the generic layers reach a task only through its description. The tasks
# package's root registers their envs with gymnasium, so it sits with them.
TASK_PACKAGES = tuple(f"policy_composer.tasks.{p.name}" for p in sorted((ROOT / "tasks").iterdir())
                      if (p / "__init__.py").is_file())
# The seven layers, lowest first: a module may import its own layer and the layers below it, never one above.
LAYERS = {"task core": ("policy_composer.tasks",), "dataset I/O": ("policy_composer.data",),
          "learning kernel": ("policy_composer.learning",), "controllers": ("policy_composer.policies",),
          "selector": ("policy_composer.selector",), "tasks": TASK_PACKAGES, "application": ("policy_composer.app",)}
GENERIC = ("task core", "dataset I/O", "learning kernel", "controllers", "selector")


def _under(module: str, prefix: str) -> bool:
    return module == prefix or module.startswith(prefix + ".")


def layer(module: str) -> int | None:
    """The layer of `module`: the one whose prefix it is under, the longest prefix deciding."""
    if module == "policy_composer.tasks":
        return list(LAYERS).index("tasks")
    found = [(len(p), i) for i, prefixes in enumerate(LAYERS.values()) for p in prefixes if _under(module, p)]
    return max(found)[1] if found else None


def module_name(path: Path, root: Path = ROOT) -> str:
    rel = path.relative_to(root).with_suffix("")
    parts = rel.parts if rel.parts[0] == "policy_composer" else ("policy_composer", *rel.parts)
    return ".".join(parts).removesuffix(".__init__")


def imports(path: Path):
    """(line, module) for every import of the project's code in `path`, function-level ones included."""
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [f"{node.module}.{a.name}" for a in node.names]
        else:
            continue
        yield from ((node.lineno, n) for n in names if n.split(".")[0] in ("policy_composer", *CARD_FOLDERS))


def source_files():
    """Every module once, under its real folder (the symlinks under policy_composer/ are skipped)."""
    own = [p for p in (ROOT / "policy_composer").rglob("*.py") if p.relative_to(ROOT).parts[1] not in CARD_FOLDERS]
    return sorted([*own, *(p for folder in CARD_FOLDERS for p in (ROOT / folder).rglob("*.py"))])


def test_the_card_folders_are_the_import_roots_subpackages():
    for folder in CARD_FOLDERS:
        link = ROOT / "policy_composer" / folder
        assert link.is_symlink() and link.resolve() == ROOT / folder, link


def test_every_module_is_in_one_of_seven_layers_and_imports_downward():
    unplaced, upward, bare = [], [], []
    for path in source_files():
        me = module_name(path)
        if me == "policy_composer":  # the root package: its version, nothing of the project
            assert not list(imports(path)), "policy_composer/__init__.py imports the project"
            continue
        if layer(me) is None:
            unplaced.append(str(path.relative_to(ROOT)))
            continue
        for line, target in imports(path):
            where = f"{path.relative_to(ROOT)}:{line}"
            if not target.startswith("policy_composer."):
                bare.append(f"{where} imports {target}")
            elif layer(target) is None or layer(target) > layer(me):
                upward.append(f"{where} ({list(LAYERS)[layer(me)]}) imports {target}")
    assert not unplaced, f"modules outside the seven layers: {unplaced}"
    assert not bare, "import through the root, policy_composer.*:\n" + "\n".join(bare)
    assert not upward, "a lower layer imports a higher one:\n" + "\n".join(upward)


def test_the_generic_layers_name_no_task():
    """The controller kinds, the recorder, the world model and the selector read a task through its description
    (`policy_composer.tasks.registry`): no generic module imports a task's package, and every task the registry lists
    is such a package."""
    naming = {}
    for path in source_files():
        me = module_name(path)
        if layer(me) is None or list(LAYERS)[layer(me)] not in GENERIC:
            continue
        tasks = sorted({t for _, t in imports(path) if any(_under(t, p) for p in TASK_PACKAGES)})
        if tasks:
            naming[me] = tasks
    assert not naming, naming
    assert set(TASKS.values()) <= set(TASK_PACKAGES)


def test_layer_check_catches_an_upward_import(tmp_path):
    """The check itself: a controller module that reaches into the application, inside a function, is flagged."""
    bad = tmp_path / "policies" / "probe.py"
    bad.parent.mkdir()
    bad.write_text("def f():\n    from policy_composer.app.demo import run_demo\n")
    found = [(module_name(bad, tmp_path), target) for _, target in imports(bad)]
    assert found == [("policy_composer.policies.probe", "policy_composer.app.demo.run_demo")]
    assert layer(found[0][1]) > layer(found[0][0])


def _unresolved_imports(root: Path) -> list[str]:
    """basedpyright's unresolved imports and unknown imported names (pyproject's [tool.basedpyright])."""
    exe = shutil.which("basedpyright", path=str(Path(sys.executable).parent))
    result = subprocess.run([exe, "--outputjson", "--pythonpath", sys.executable, "--project", str(root)], cwd=root,
                            capture_output=True, text=True, timeout=600)
    report = json.loads(result.stdout)
    assert report["summary"]["filesAnalyzed"] > 0, result.stderr
    return [f"{Path(d['file']).relative_to(root)}:{d['range']['start']['line'] + 1}: {d['message']}"
            for d in report["generalDiagnostics"]
            if d.get("rule") == "reportMissingImports" or "is unknown import symbol" in d["message"]]


def test_a_static_checker_resolves_every_import_and_catches_a_broken_one(tmp_path):
    """What an IDE or an import graph sees: every `policy_composer.*` import, and every name imported from it,
    resolves in a copy of the project, except the two broken ones planted in it (one run of the checker proves both:
    the project is clean, and the check would see it if it were not)."""
    copy = tmp_path / "repo"
    for name in ("policy_composer", *CARD_FOLDERS, "tests", "benchmarks", "plugins", "pyproject.toml"):
        src = ROOT / name
        if src.is_dir():
            shutil.copytree(src, copy / name, symlinks=True, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy(src, copy / name)
    with open(copy / "selector" / "core.py", "a") as f:
        f.write("from policy_composer.selector.no_such_module import x\n")
    with open(copy / "tasks" / "gear_assembly" / "spec.py", "a") as f:
        f.write("from policy_composer.policies.registry import no_such_name\n")
    found = _unresolved_imports(copy)
    planted = [m for m in found if (m.startswith("selector/core.py") and "no_such_module" in m)
               or (m.startswith("tasks/gear_assembly/spec.py") and "no_such_name" in m)]
    assert len(planted) == 2, found
    assert [m for m in found if m not in planted] == []


@pytest.mark.parametrize("name, importable", [("tasks", False), ("policies", False), ("selector", False),
                                              ("policy_composer.tasks", True), ("policy_composer.policies", True),
                                              ("policy_composer.selector", True), ("policy_composer.data", True)])
def test_one_import_root(tmp_path, name, importable):
    """Installed, the project is `policy_composer` only: generic names like `tasks` do not leak into site-packages."""
    result = subprocess.run([sys.executable, "-c", f"import {name}"], cwd=tmp_path, capture_output=True, text=True)
    assert (result.returncode == 0) == importable, result.stderr


def test_import_datasets_from_repo_root_is_huggingface():
    out = subprocess.run([sys.executable, "-c",
                          "import datasets; print(datasets.__file__); print(datasets.load_dataset)"],
                         cwd=ROOT, capture_output=True, text=True, check=True).stdout
    path = out.splitlines()[0]
    assert "site-packages" in path and not path.startswith(str(ROOT / "datasets")), path


def test_the_command_line_runs_as_a_module():
    out = subprocess.run([sys.executable, "-m", "policy_composer.app.cli", "--help"], cwd=ROOT, capture_output=True,
                         text=True, check=True)
    assert "demo" in out.stdout


def test_ruff_is_clean():
    """The linter CI runs (LeRobot's, configured in pyproject.toml)."""
    result = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", str(ROOT)], capture_output=True,
                            text=True)
    assert result.returncode == 0, result.stdout[-3000:]
