"""Reads a csmetro NeXus export with real readers (h5py, nexusformat) and checks it against
the campaign's CSV/JSON results: python3 check_nexus.py FILE.nxs RESULTS_DIR.
Exit 0 and one line `ok: ...` when every check holds; any failure raises."""
import csv
import json
import math
import os
import sys

import h5py
import nexusformat.nexus as nx


def same(a, b):
    return (math.isnan(a) and math.isnan(b)) or a == b


def main(path, results):
    checked = 0
    with h5py.File(path, "r") as f:
        assert f.attrs["NX_class"] == "NXroot", dict(f.attrs)
        entry = f[f.attrs["default"]]
        assert entry.attrs["NX_class"] == "NXentry"
        # The default plot resolves: entry -> NXdata -> its signal and axes datasets.
        data = entry[entry.attrs["default"]]
        assert data.attrs["NX_class"] == "NXdata"
        signal_name = data.attrs["signal"]
        signal = data[signal_name]
        axes = data[data.attrs["axes"]]
        assert signal.shape == axes.shape and signal.shape[0] > 1
        assert axes.attrs["units"] == "um"
        assert entry["notes/campaign/data"][()].decode().startswith("[campaign]") or \
            "[campaign]" in entry["notes/campaign/data"][()].decode()
        # Every CSV result, column by column, value by value.
        for name in sorted(os.listdir(results)):
            if not name.endswith(".csv"):
                continue
            g = entry[name[:-4]]
            with open(os.path.join(results, name), newline="") as fh:
                rows = list(csv.reader(fh))
            head, body = rows[0], rows[1:]
            for i, col in enumerate(head):
                ds = g[col]
                cells = [r[i].strip() for r in body]
                if ds.dtype.kind == "f":
                    want = [float(c) if c else float("nan") for c in cells]
                    got = list(ds[()])
                    assert len(got) == len(want), (name, col)
                    assert all(same(a, b) for a, b in zip(got, want)), (name, col)
                    if col.endswith("_um"):
                        assert ds.attrs["units"] == "um", (name, col)
                else:
                    got = [x.decode() if isinstance(x, bytes) else x for x in ds[()]]
                    assert got == cells, (name, col)
                checked += len(cells)
        # The ISO 230-2 figures, key by key.
        iso = json.load(open(os.path.join(results, "iso230.json")))

        def walk(v, g, key):
            nonlocal checked
            if v is None:
                assert key not in g, key
            elif isinstance(v, bool):
                assert g[key][()] == (1.0 if v else 0.0), key
            elif isinstance(v, (int, float)):
                assert g[key][()] == float(v), (key, g[key][()], v)
                checked += 1
            elif isinstance(v, str):
                assert g[key][()].decode() == v, key
            elif isinstance(v, dict):
                for k, x in v.items():
                    walk(x, g[key], k)
            elif isinstance(v, list) and v and all(isinstance(x, (int, float)) for x in v):
                assert list(g[key][()]) == [float(x) for x in v], key
            elif isinstance(v, list) and v and all(isinstance(x, str) for x in v):
                assert [x.decode() for x in g[key][()]] == v, key
            elif isinstance(v, list):
                for i, x in enumerate(v):
                    walk(x, g[key], str(i))

        walk(iso, entry, "iso230")
    # nexusformat: the tree loads and its default plot is found by NeXus's own rules.
    root = nx.nxload(path)
    plot = root.plottable_data
    assert plot is not None and plot.nxsignal is not None, root.tree[:2000]
    assert plot.nxsignal.nxname == signal_name
    print(f"ok: {checked} values equal, default plot {plot.nxpath}")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
