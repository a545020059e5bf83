"""Convert a pickled SMPL-family model file (``.pkl``) into the ``.npz`` layout lfit reads.

The SMPL, SMPL+H, MANO and FLAME pickles hold some arrays as ``chumpy`` objects, a package that
no longer installs on current Python; loading them with ``pickle`` fails without it. This reads
them without chumpy: a chumpy array is taken from the value it was pickled with (its ``x``), a
scipy sparse matrix (SMPL's ``J_regressor``) is made dense, and the SMPL-layout members are
written with ``numpy.savez`` — to a temporary file renamed into place, so nothing is half-written.

    python -m lfit.convert_pkl basicModel_neutral_lbs_10_207_0_v1.0.0.pkl smpl.npz

Needs numpy (and scipy where the file holds a sparse matrix); lfit ships no SMPL-family file
(their licences forbid it): convert the one you have.
"""

import os
import pickle
import sys
import tempfile

import numpy as np

#: The members of an SMPL-layout model file that lfit reads (``lfit model info`` lists what a
#: converted file holds).
MEMBERS = ("v_template", "f", "weights", "kintree_table", "J_regressor", "shapedirs", "posedirs")


class _Chumpy:
    """Stands for any chumpy class while unpickling: keeps the pickled state."""

    def __init__(self, *args, **kwargs):
        self._state = None

    def __setstate__(self, state):
        # A pickled state may come as (dict, slots).
        if isinstance(state, tuple) and len(state) == 2 and isinstance(state[0], dict):
            state = state[0]
        self._state = state

    def value(self):
        state = self._state
        if isinstance(state, dict) and "x" in state:
            return np.asarray(state["x"])
        raise ValueError("a chumpy object without a pickled value ('x'): not a model array")


class _Unpickler(pickle.Unpickler):
    def find_class(self, module, name):
        if module == "chumpy" or module.startswith("chumpy."):
            return _Chumpy
        return super().find_class(module, name)


def _array(key, value):
    if isinstance(value, _Chumpy):
        return value.value()
    if hasattr(value, "toarray") and hasattr(value, "nnz"):  # a scipy sparse matrix
        return np.asarray(value.toarray())
    array = np.asarray(value)
    if array.dtype == object:
        raise ValueError(f"'{key}' is not a numeric array")
    return array


def read_pkl(path):
    """The SMPL-layout members of the pickled model file at ``path``, as numpy arrays."""
    with open(path, "rb") as f:
        data = _Unpickler(f, encoding="latin1").load()
    if not isinstance(data, dict):
        raise ValueError(f"{path}: not a pickled model (a dict of arrays), but {type(data).__name__}")
    missing = [k for k in ("v_template", "f", "weights", "kintree_table", "J_regressor") if k not in data]
    if missing:
        raise ValueError(f"{path}: no {', '.join(missing)}: not an SMPL-family model file")
    return {k: _array(k, data[k]) for k in MEMBERS if k in data}


def convert_pkl(path, out):
    """Writes the SMPL-layout members of the pickled model at ``path`` to ``out`` (``.npz``),
    atomically; returns the member names written."""
    arrays = read_pkl(path)
    out = os.fspath(out)
    folder = os.path.dirname(os.path.abspath(out))
    fd, tmp = tempfile.mkstemp(suffix=".npz", dir=folder)
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez(f, **arrays)
        os.replace(tmp, out)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise
    return sorted(arrays)


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 2 or argv[0] in ("-h", "--help"):
        print("usage: python -m lfit.convert_pkl MODEL.pkl OUT.npz", file=sys.stderr)
        return 2
    try:
        names = convert_pkl(argv[0], argv[1])
    except (OSError, ValueError, pickle.UnpicklingError, EOFError, ImportError, AttributeError, TypeError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    print(f"wrote {argv[1]}: {', '.join(names)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
