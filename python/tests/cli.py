"""Running the command-line tools beside the package, for the tests that compare the two."""
import os
import pathlib
import subprocess

# The tools of the build the package was made from (scripts/python_test.sh sets DSR_TOOLS).
TOOLS = pathlib.Path(
    os.environ.get("DSR_TOOLS", pathlib.Path(__file__).parents[2] / "build" / "tools")).resolve()


def run_tool(tool, *args, cwd=None):
    return subprocess.run([str(TOOLS / tool), *args], capture_output=True, text=True, cwd=cwd)


def cli_flags(options):
    """--name=value for each option; a list or tuple value as comma-separated items."""
    return [f"--{name}={','.join(map(str, value)) if isinstance(value, (list, tuple)) else value}"
            for name, value in options.items()]


def error_line(tool, *args, cwd=None):
    """The one error line `tool` prints for `args` (after "error: "), checking exit code 2."""
    run = run_tool(tool, *args, cwd=cwd)
    assert run.returncode == 2, run.stderr
    lines = [line for line in run.stderr.splitlines() if ": error: " in line]
    assert len(lines) == 1, run.stderr
    return lines[0].split(": error: ", 1)[1]
