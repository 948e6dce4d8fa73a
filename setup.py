"""Builds the compiled per-step recorder, ``episode_audit.record._stepfast``, when it can.

Everything else is in ``pyproject.toml``. Without a C compiler (or with a build that fails) the
package installs without the extension and the recorder takes its pure-Python path, which writes
the same files, a little slower (``docs/recording.md``, "The compiled step");
``EPISODE_AUDIT_REQUIRE_EXTENSION=1`` makes a failed build an error instead (the Makefile sets it).
"""

from __future__ import annotations

import os
import sys

import numpy
from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext

# the files of episode_audit/record/csrc/ (stepfast.h lists them)
_C_FILES = ("module", "step", "wrapper", "records", "blocks", "vector")


class OptionalBuildExt(build_ext):
    """``build_ext`` that warns and goes on when the extension cannot be built."""

    def build_extensions(self) -> None:
        """Build each extension; one that fails is left out of what is installed."""
        for ext in list(self.extensions):
            if not self._built(ext):
                self.extensions.remove(ext)  # (an editable install would copy its output)

    def _built(self, ext: Extension) -> bool:
        """Build ``ext``; on failure warn (or raise, if the environment requires it)."""
        try:
            self.build_extension(ext)
        except Exception as exc:  # the compiler's failure, in whatever class distutils gave it
            if os.environ.get("EPISODE_AUDIT_REQUIRE_EXTENSION") == "1":
                raise
            print(
                f"episode-audit: the compiled step ({ext.name}) was not built ({exc}); "
                "the recorder takes its pure-Python path",
                file=sys.stderr,
            )
            return False
        return True


setup(
    ext_modules=[
        Extension(
            "episode_audit.record._stepfast",
            [f"episode_audit/record/csrc/{name}.c" for name in _C_FILES],
            include_dirs=[numpy.get_include()],
            depends=["episode_audit/record/csrc/stepfast.h"],
            # hidden: only the module's init function is exported, not the files' shared names
            extra_compile_args=["-O2", "-fvisibility=hidden"] if os.name != "nt" else [],
        )
    ],
    cmdclass={"build_ext": OptionalBuildExt},
)
