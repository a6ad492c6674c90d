"""setup.py's per-kernel compiler flags."""

import ast
from pathlib import Path

SETUP = Path(__file__).resolve().parent.parent / "setup.py"


def _strings(tree: ast.AST) -> list[str]:
    return [node.value for node in ast.walk(tree) if isinstance(node, ast.Constant) and isinstance(node.value, str)]


def test_no_kernel_redefines_cythons_inline_macro() -> None:
    # -DCYTHON_INLINE=... always_inline forces every Cython utility function inline as
    # well, and Cython 3.0.8 (pyproject's lowest) makes some of them recursive: gcc then
    # refuses the build ("inlining failed in call to always_inline ... recursive
    # inlining"). _elements forces only its own row walk inline, in C.
    flags = [s for s in _strings(ast.parse(SETUP.read_text())) if s.startswith("-D")]
    assert not any(flag.startswith("-DCYTHON_INLINE") for flag in flags), flags
