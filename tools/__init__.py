"""Probes and converters that live outside the package (run from the repository root as ``python -m tools.<name>``).

Each script ends with ``sys.exit(run_script(main))``: bad input is one line on stderr and exit status 2, as the
``gnn-mp`` command's (``python -m tools.fuzz_tools`` feeds every flag of every script bad values)."""

from __future__ import annotations

import sys
from typing import Callable


def run_script(main: Callable[[], "int | None"]) -> int:
    """``main()``, with what bad input raises in a script (an unknown task or sampler, a value out of a
    function's range or too large, a file that cannot be read or written, a usage error) as one line
    naming the script: ``python -m tools.<name>: error: ...``, exit status 2. Ctrl-C is one line too
    (130)."""
    from train.args import UsageError
    prog = "python -m " + getattr(getattr(sys.modules.get("__main__"), "__spec__", None), "name", "tools")
    try:
        return int(main() or 0)
    except KeyboardInterrupt:
        print(f"{prog}: error: interrupted", file=sys.stderr)
        return 130
    except (UsageError, ValueError, OverflowError, OSError) as exc:
        if isinstance(exc, OSError) and exc.filename:
            message = f"{exc.strerror or exc}: {exc.filename}"
        else:
            message = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        print(f"{prog}: error: {message}", file=sys.stderr)
        return 2
