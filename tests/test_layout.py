"""The layout: one import root, layers that import downward, and no shadowing of Hugging Face's `datasets`."""

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# The design card's folders install under the one import root (pyproject's package-dir).
FOLDERS = {"policy_composer": "policy_composer", "policy_composer.tasks": "tasks",
           "policy_composer.policies": "policies", "policy_composer.selector": "selector"}
# Lowest first: a module may import its own layer and the layers below it, never one above.
LAYERS = ("policy_composer.tasks", "policy_composer.data", "policy_composer.learning", "policy_composer.policies",
          "policy_composer.selector", "policy_composer")


def layer(module: str) -> int:
    return next(i for i, prefix in enumerate(LAYERS) if module == prefix or module.startswith(prefix + "."))


def module_name(path: Path, root: Path = ROOT) -> str:
    rel = path.relative_to(root).with_suffix("")
    package = next(pkg for pkg, folder in FOLDERS.items() if rel.parts[0] == folder)
    return ".".join([package, *rel.parts[1:]]).removesuffix(".__init__")


def imports(path: Path):
    """(line, module) for every import of the project's code in `path`, function-level ones included."""
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [f"{node.module}.{a.name}" for a in node.names]
        else:
            continue
        yield from ((node.lineno, n) for n in names if n.split(".")[0] in ("policy_composer", *FOLDERS.values()))


def source_files():
    return sorted(p for folder in FOLDERS.values() for p in (ROOT / folder).rglob("*.py"))


def test_layers_import_downward():
    upward, bare = [], []
    for path in source_files():
        me = module_name(path)
        for line, target in imports(path):
            if not target.startswith("policy_composer"):
                bare.append(f"{path.relative_to(ROOT)}:{line} imports {target}")
            elif layer(target) > layer(me):
                upward.append(f"{path.relative_to(ROOT)}:{line} ({LAYERS[layer(me)]}) imports {target}")
    assert not bare, "import through the root, policy_composer.*:\n" + "\n".join(bare)
    assert not upward, "a lower layer imports a higher one:\n" + "\n".join(upward)


def test_layer_check_catches_an_upward_import(tmp_path):
    """The check itself: a controller module that reaches into the application, inside a function, is flagged."""
    bad = tmp_path / "policies" / "probe.py"
    bad.parent.mkdir()
    bad.write_text("def f():\n    from policy_composer.demo import run_demo\n")
    found = [(module_name(bad, tmp_path), target) for _, target in imports(bad)]
    assert found == [("policy_composer.policies.probe", "policy_composer.demo.run_demo")]
    assert layer(found[0][1]) > layer(found[0][0])


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


def test_console_command_lists_demo():
    out = subprocess.run([sys.executable, "-m", "policy_composer.cli", "--help"], cwd=ROOT, capture_output=True,
                         text=True, check=True)
    assert "demo" in out.stdout


def test_ruff_is_clean():
    """The linter CI runs (LeRobot's, configured in pyproject.toml)."""
    result = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", str(ROOT)], capture_output=True,
                            text=True)
    assert result.returncode == 0, result.stdout[-3000:]
