"""Access to the compiled kernels (jsar/features/_kernels.c), with a clear error when they are not built."""
from __future__ import annotations

# Must equal KERNELS_ABI in _kernels.c: a build older than the sources fails loudly, not subtly.
EXPECTED_ABI = 8

try:
    from jsar.features import _kernels as kernels
except ImportError as exc:  # pragma: no cover - depends on the installation
    raise ImportError(
        "jsar.features._kernels is not built: install the project with `make test` / `make run` or "
        "`pip install -e .` (needs a C compiler; it builds from jsar/features/_kernels.c)"
    ) from exc

if getattr(kernels, "abi", None) != EXPECTED_ABI:  # pragma: no cover - depends on the installation
    raise ImportError(
        f"jsar.features._kernels is stale (abi {getattr(kernels, 'abi', None)}, sources need {EXPECTED_ABI}): "
        "rebuild with `pip install -e .`"
    )

__all__ = ["kernels"]
