"""The README's two commands are the ones CI and newcomers run."""

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_ci_runs_the_readme_test_command():
    readme = (ROOT / "README.md").read_text()
    commands = [line.strip() for line in readme.split("```")[1].splitlines()[1:]
                if line.strip() and not line.startswith("#")]
    setup_and_demo, setup_and_test = commands[:2]
    assert "scripts/setup.sh" in setup_and_demo and "policy-composer demo" in setup_and_demo
    assert setup_and_test in (ROOT / ".ci" / "run").read_text()
