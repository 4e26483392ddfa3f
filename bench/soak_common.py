"""Helpers shared by the soak benchmarks (bench/soak.py, bench/rt_soak.py): the program to run,
the work folder, and the JSON figures written out. Not a benchmark itself."""
import json
import os
import sys
import tempfile


def hapticloud_exe(build, who):
    """The hapticloud program of the release build folder `build`; exits naming it when absent."""
    exe = os.path.join(build, "apps", "hapticloud", "hapticloud")
    if not os.access(exe, os.X_OK):
        sys.exit(f"{who}: {exe} not found: build the release preset first")
    return exe


def work_folder(keep, prefix):
    """(folder, temporary) for the work files: `keep` when given (created if missing, kept), else
    a temporary folder removed by temporary.cleanup()."""
    if keep:
        os.makedirs(keep, exist_ok=True)
        return keep, None
    tmp = tempfile.TemporaryDirectory(prefix=prefix)
    return tmp.name, tmp


def emit(results, out):
    """Prints the figures as JSON on stdout, and writes them to `out` too when given."""
    text = json.dumps(results, indent=2)
    print(text)
    if out:
        with open(out, "w") as f:
            f.write(text + "\n")
