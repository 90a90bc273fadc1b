"""The README's example runs as written, so that it cannot rot.

The test runs the first ```python block under the README's "## Example" heading, changing one thing: the number in
its ``total_timesteps=...`` (the training budget) becomes :data:`BUDGET`, so that it trains one rollout instead of
the README's budget. Everything else (the environment, the model, save, load and the evaluation) is the README's code.
"""

import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"
#: The training budget the test gives the example (agent-steps; EM-PPO still collects one whole rollout).
BUDGET = 1


def example() -> str:
    text = README.read_text()
    assert "\n## Example\n" in text, "the README has no '## Example' heading"
    after = text.split("\n## Example\n", 1)[1]
    assert "```python\n" in after, "no python block under the README's example heading"
    return after.split("```python\n", 1)[1].split("```", 1)[0]


def test_the_readmes_example_runs_as_written(tmp_path, monkeypatch, capsys):
    code = example()
    assert "evaluate_policy(" in code and ".save(" in code and ".load(" in code
    scaled, n = re.subn(r"total_timesteps=[0-9_]+", f"total_timesteps={BUDGET}", code)
    assert n == 1, "the example must give its budget as total_timesteps=<number>, once"
    monkeypatch.chdir(tmp_path)  # (the example saves its model in the working directory)
    exec(compile(scaled, str(README), "exec"), {"__name__": "readme_example"})
    assert re.search(r"team reward per episode: -?[0-9.]+ \+/- [0-9.]+", capsys.readouterr().out)


def test_the_readme_stays_short():
    assert len(README.read_text().splitlines()) <= 130
