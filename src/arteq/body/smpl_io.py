"""Readers for SMPL-format model files (official SMPL / SMPL-H ``.pkl`` and ``.npz``, and anny22 ``.npz``).

The official ``.pkl`` files pickle ``chumpy`` objects and ``scipy.sparse`` matrices. They are read WITHOUT
chumpy and without running arbitrary pickled code: :class:`SafeModelUnpickler` resolves only a small
whitelist of globals (numpy array reconstruction, scipy sparse csc/csr matrices, chumpy arrays mapped to a
stand-in that keeps the array) and refuses everything else. Pickled entries of an ``.npz`` (object arrays,
e.g. a sparse ``J_regressor`` saved by ``np.savez``, SMPL-X's ``joint2num``) go through the same unpickler.

Files as users have them: SMPL v1.0 (``basicModel_f_lbs_10_207_0_v1.0.0.pkl``,
``basicmodel_m_lbs_10_207_0_v1.0.0.pkl``, SMPLify's ``basicModel_neutral_lbs_10_207_0_v1.0.0.pkl``), SMPL v1.1
(``basicmodel_{neutral,m,f}_lbs_10_207_0_v1.1.0.pkl``, renamed ``SMPL_NEUTRAL.pkl`` / ``SMPL_MALE.pkl`` /
``SMPL_FEMALE.pkl`` for smplx), SMPL+H (MANO's ``SMPLH_male.pkl``, AMASS's ``smplh/<gender>/model.npz``),
and their chumpy-free ``.pkl`` / ``.npz`` conversions (smplx's tools, ``np.savez`` of the unpickled dict).

:func:`read_model_file` returns the raw arrays; :func:`to_body22` folds any SMPL-format joint set (24 for
SMPL, 52 for SMPL-H) into the 22 body joints: joints beyond 21 are folded into their nearest ancestor among
the first 22 (hands into wrists) for the skinning weights and dropped from the regressor and posedirs.
"""

from __future__ import annotations

import codecs
import copyreg
import io
import pickle
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from arteq.body.skeleton import NUM_JOINTS, PARENTS

REQUIRED_KEYS = ("v_template", "shapedirs", "posedirs", "J_regressor", "weights", "kintree_table", "f")

LICENSE_HINT = (
    "SMPL / SMPL-H model files are licensed: obtain them from https://smpl.is.tue.mpg.de (or "
    "https://mano.is.tue.mpg.de for SMPL-H) and point the config key `body_model.model_path=...` at the file."
)


class BodyModelFileError(ValueError):
    """A body model file is missing, unreadable or does not hold a SMPL-format model."""


class UnsafePickleError(pickle.UnpicklingError):
    """A body model pickle (or pickled ``.npz`` entry) asked for a global outside the whitelist."""


class _ChumpyStandIn:
    """Stand-in for chumpy objects: keeps the pickled state; the array is ``.r`` (the ``x`` entry)."""

    def __setstate__(self, state: Any) -> None:
        self.state = state if isinstance(state, dict) else {"x": state}

    @property
    def r(self) -> np.ndarray:
        for key in ("x", "_x", "r"):
            if key in self.state:
                return np.asarray(self.state[key])
        raise BodyModelFileError(f"chumpy object without an array (state keys {sorted(self.state)})")

    x = r


class _SparseStandIn:
    """Stand-in for pickled ``scipy.sparse`` csc/csr matrices: rebuilt from their arrays on demand."""

    kind = "csc"

    def __setstate__(self, state: dict) -> None:
        self.state = state

    def toarray(self) -> np.ndarray:
        import scipy.sparse

        st = self.state
        shape = tuple(st.get("_shape", st.get("shape")))
        cls = scipy.sparse.csc_matrix if self.kind == "csc" else scipy.sparse.csr_matrix
        return cls((st["data"], st["indices"], st["indptr"]), shape=shape).toarray()


class _CsrStandIn(_SparseStandIn):
    kind = "csr"


def _np_module_names(*names: str) -> list[str]:
    return [f"{prefix}.{n}" for prefix in ("numpy.core", "numpy._core") for n in names]


_ALLOWED: dict[str, Any] = {
    "numpy.ndarray": np.ndarray,
    "numpy.dtype": np.dtype,
    "copy_reg._reconstructor": copyreg._reconstructor,
    "copyreg._reconstructor": copyreg._reconstructor,
    "__builtin__.object": object,
    "builtins.object": object,
    "_codecs.encode": codecs.encode,  # how protocol-2 pickles from Python 3 store bytes
    "__builtin__.set": set,
    "builtins.set": set,
    "__builtin__.frozenset": frozenset,
    "builtins.frozenset": frozenset,
}
_RECONSTRUCT = np.zeros(1).__reduce__()[0]  # numpy's array reconstructor, whatever its module path
_SCALAR = np.float64(0).__reduce__()[0]
for _n in _np_module_names("multiarray._reconstruct"):
    _ALLOWED[_n] = _RECONSTRUCT
for _n in _np_module_names("multiarray.scalar"):
    _ALLOWED[_n] = _SCALAR
_FROMBUFFER = np.zeros(1).__reduce_ex__(5)[0]  # protocol-5 array reconstruction (bytes, dtype, shape, order)
for _n in _np_module_names("numeric._frombuffer"):
    _ALLOWED[_n] = _FROMBUFFER
for _mod in ("scipy.sparse.csc", "scipy.sparse._csc"):
    _ALLOWED[f"{_mod}.csc_matrix"] = _SparseStandIn
    _ALLOWED[f"{_mod}.csc_array"] = _SparseStandIn
for _mod in ("scipy.sparse.csr", "scipy.sparse._csr"):
    _ALLOWED[f"{_mod}.csr_matrix"] = _CsrStandIn
    _ALLOWED[f"{_mod}.csr_array"] = _CsrStandIn
for _cls in ("ch.Ch", "ch_ops.add", "ch_ops.subtract", "ch_ops.multiply", "reordering.Select"):
    _ALLOWED[f"chumpy.{_cls}"] = _ChumpyStandIn


class SafeModelUnpickler(pickle.Unpickler):
    """A ``pickle.Unpickler`` that resolves only whitelisted globals (arrays, sparse matrices, chumpy)."""

    def __init__(self, file, *, source: str = "<stream>") -> None:
        super().__init__(file, encoding="latin1")
        self.source = source

    def find_class(self, module: str, name: str) -> Any:
        obj = _ALLOWED.get(f"{module}.{name}")
        if obj is None:
            raise UnsafePickleError(
                f"{self.source}: refusing to load global '{module}.{name}' — only numpy arrays, "
                "scipy sparse matrices and chumpy arrays are allowed in a body model pickle"
            )
        return obj


def _to_array(value: Any) -> np.ndarray:
    if isinstance(value, np.ndarray) and value.dtype.hasobject and value.shape == ():
        value = value.item()  # an object pickled into an .npz entry (e.g. a sparse matrix)
    if isinstance(value, _SparseStandIn):
        return value.toarray()
    if isinstance(value, _ChumpyStandIn):
        return value.r
    if hasattr(value, "toarray"):  # a real scipy sparse matrix (e.g. from an npz written by a tool)
        return value.toarray()
    return np.asarray(value)


def _read_npz(path: Path) -> dict[str, Any]:
    """All entries of an ``.npz``; pickled (object) entries are read with :class:`SafeModelUnpickler`."""
    out: dict[str, Any] = {}
    with np.load(path, allow_pickle=False) as z:
        names = list(z.files)
        for key in names:
            try:
                out[key] = z[key]
            except ValueError:  # an object array: numpy would unpickle it; we do, restricted
                out[key] = None
    pickled = [k for k, v in out.items() if v is None]
    if pickled:
        with zipfile.ZipFile(path) as zf:
            for key in pickled:
                with zf.open(f"{key}.npy") as fh:
                    version = np.lib.format.read_magic(fh)
                    if version == (1, 0):
                        np.lib.format.read_array_header_1_0(fh)
                    else:
                        np.lib.format.read_array_header_2_0(fh)
                    out[key] = SafeModelUnpickler(fh, source=f"{path}['{key}']").load()
    return out


def read_model_file(path: str | Path) -> dict[str, np.ndarray]:
    """Read an SMPL-format model file (``.pkl`` or ``.npz``) into plain numpy arrays.

    Returns a dict with at least :data:`REQUIRED_KEYS`; other array entries are kept as they are.
    Raises :class:`BodyModelFileError` naming the file on any problem.
    """
    path = Path(path).expanduser()
    if not path.is_file():
        raise BodyModelFileError(f"body model file not found: '{path}'. {LICENSE_HINT}")
    suffix = path.suffix.lower()
    try:
        if suffix == ".npz":
            raw = _read_npz(path)
        elif suffix == ".pkl":
            with open(path, "rb") as fh:
                raw = SafeModelUnpickler(io.BufferedReader(fh), source=str(path)).load()
            if not isinstance(raw, dict):
                raise BodyModelFileError(f"'{path}': expected a pickled dict, got {type(raw).__name__}")
        else:
            raise BodyModelFileError(f"'{path}': unsupported extension '{suffix}' (expected .npz or .pkl)")
    except (UnsafePickleError, BodyModelFileError):
        raise
    except (OSError, EOFError, ValueError, zipfile.BadZipFile, pickle.PickleError, KeyError, TypeError,
            AttributeError, IndexError) as exc:  # fmt: skip
        raise BodyModelFileError(
            f"'{path}' is not a readable SMPL-format model file ({type(exc).__name__}: {exc}). {LICENSE_HINT}"
        ) from exc
    missing = [k for k in REQUIRED_KEYS if k not in raw]
    if missing:
        raise BodyModelFileError(
            f"'{path}' lacks the SMPL model keys {missing} (has {sorted(raw)}). {LICENSE_HINT}"
        )
    out: dict[str, np.ndarray] = {}
    for key, value in raw.items():
        if not isinstance(key, str):
            continue
        try:
            out[key] = _to_array(value)
        except (ValueError, TypeError, KeyError) as exc:
            if key in REQUIRED_KEYS:
                raise BodyModelFileError(f"'{path}': cannot read entry '{key}': {exc}") from exc
    return out


def to_body22(raw: dict[str, np.ndarray], source: str = "<model>") -> dict[str, np.ndarray]:
    """Convert raw SMPL-format arrays to the 22-joint layout used by :func:`arteq.body.lbs.lbs`.

    Returns float64 ``v_template [V,3]``, ``shapedirs [V,3,NB]``, ``posedirs [P,V*3]`` (``P = 0`` when the
    file has no pose correctives), ``J_regressor [22,V]``, ``weights [V,22]``, int64 ``faces [F,3]``.
    """

    def bad(msg: str) -> BodyModelFileError:
        return BodyModelFileError(f"'{source}': {msg}")

    v = np.asarray(raw["v_template"], dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3 or v.shape[0] == 0:
        raise bad(f"v_template must be [V, 3], got {list(v.shape)}")
    V = v.shape[0]
    sd = np.asarray(raw["shapedirs"], dtype=np.float64)
    if sd.ndim != 3 or sd.shape[:2] != (V, 3):
        raise bad(f"shapedirs must be [{V}, 3, NB], got {list(sd.shape)}")
    kt = np.asarray(raw["kintree_table"]).astype(np.int64)
    if kt.ndim != 2 or kt.shape[0] != 2 or kt.shape[1] < NUM_JOINTS:
        raise bad(f"kintree_table must be [2, J>=22], got {list(kt.shape)}")
    J = kt.shape[1]
    ids = kt[1]
    pos = {int(i): n for n, i in enumerate(ids)}
    parents = [-1] + [pos.get(int(p), -2) for p in kt[0, 1:]]
    if -2 in parents:
        raise bad("kintree_table references unknown parent joints")
    if tuple(parents[:NUM_JOINTS]) != PARENTS:
        raise bad(f"the first 22 joints' parents {parents[:NUM_JOINTS]} are not SMPL's {list(PARENTS)}")
    w = np.asarray(raw["weights"], dtype=np.float64)
    if w.shape != (V, J):
        raise bad(f"weights must be [{V}, {J}], got {list(w.shape)}")
    jr = np.asarray(raw["J_regressor"], dtype=np.float64)
    if jr.shape != (J, V):
        raise bad(f"J_regressor must be [{J}, {V}], got {list(jr.shape)}")
    pd = np.asarray(raw["posedirs"], dtype=np.float64)
    if pd.ndim == 3 and pd.shape[:2] == (V, 3):
        pd = pd.reshape(V * 3, -1).T  # [P, V*3]
    elif not (pd.ndim == 2 and pd.shape[1] == V * 3):
        raise bad(f"posedirs must be [{V}, 3, P] or [P, {V * 3}], got {list(pd.shape)}")
    need = (NUM_JOINTS - 1) * 9
    if pd.shape[0] not in (0,) and pd.shape[0] < need:
        raise bad(f"posedirs has {pd.shape[0]} pose features, need 0 or >= {need}")
    f = np.asarray(raw["f"]).astype(np.int64)
    if f.ndim != 2 or f.shape[1] != 3 or f.min() < 0 or f.max() >= V:
        raise bad(f"f must be [F, 3] with indices in [0, {V}), got shape {list(f.shape)}")

    # Fold joints >= 22 into their nearest ancestor among the first 22 (SMPL hands -> wrists).
    target = list(range(J))
    for j in range(NUM_JOINTS, J):
        a = parents[j]
        while a >= NUM_JOINTS:
            a = parents[a]
        target[j] = a
    w22 = np.zeros((V, NUM_JOINTS))
    np.add.at(w22.T, np.asarray(target), w.T)
    for name, arr in (("v_template", v), ("shapedirs", sd), ("weights", w22), ("J_regressor", jr)):
        if not np.isfinite(arr).all():
            raise bad(f"{name} contains NaN or inf")
    return {
        "v_template": v,
        "shapedirs": sd,
        "posedirs": pd[:need] if pd.shape[0] else pd,
        "J_regressor": jr[:NUM_JOINTS],
        "weights": w22,
        "faces": f,
    }
