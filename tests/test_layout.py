"""The repository layout must not shadow Hugging Face's `datasets` (lerobot imports it)."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_import_datasets_from_repo_root_is_huggingface():
    out = subprocess.run([sys.executable, "-c", "import datasets; print(datasets.__file__); print(datasets.load_dataset)"],
                         cwd=ROOT, capture_output=True, text=True, check=True).stdout
    path = out.splitlines()[0]
    assert "site-packages" in path and not path.startswith(str(ROOT / "datasets")), path


def test_console_command_lists_demo():
    out = subprocess.run([sys.executable, "-m", "policy_composer.cli", "--help"], cwd=ROOT, capture_output=True, text=True, check=True)
    assert "demo" in out.stdout
