"""The README's Python example runs as written and solves the frame it renders."""
import re
from pathlib import Path

README = Path(__file__).resolve().parents[2] / "README.md"


def test_readme_python_example_runs_and_solves(capsys):
    code = re.search(r"## Python API without ROS\n\n```python\n(.*?)```", README.read_text(), re.S).group(1)
    namespace: dict = {}
    exec(compile(code, str(README), "exec"), namespace)  # noqa: S102 - our own README
    assert namespace["result"].solved
    out = capsys.readouterr().out
    assert out.startswith("solved")
