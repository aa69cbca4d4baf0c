"""Where a campaign's finished chunks go: a Zarr store or a NetCDF file written chunk by chunk
(atomically), so that a killed campaign resumes; a store made by another campaign is refused."""

from __future__ import annotations

import hashlib
import json
import os
import shutil

import equinox as eqx
import jax
import numpy as np

from ..atomic import atomic_write
from ..io.results import clean_attrs


class Store:
    """Where finished chunks go: a Zarr store (one region per chunk, a ``done`` flag per chunk
    written after its data) or a NetCDF file (one part file per chunk, written atomically, and
    the whole file assembled atomically at the end). `fingerprint` identifies the campaign: a
    store made by a different one is refused."""

    def __init__(self, path, fingerprint: str, n_chunks: int, attrs: dict | None = None):
        self.path = os.fspath(path)
        self.attrs = clean_attrs(attrs or {})  # the campaign's settings and versions, kept in the file
        self.zarr = self.path.rstrip("/").endswith(".zarr")
        self.fingerprint = fingerprint
        self.n_chunks = n_chunks
        self.parts = self.path + ".parts"
        if not self.zarr and not self.path.endswith((".nc", ".nc4", ".netcdf")):
            raise ValueError(f"out: expected a Zarr store (*.zarr) or a NetCDF file (*.nc), got {self.path!r}")

    def _check(self, attrs):
        got = attrs.get("jaxtree_campaign")
        if got is not None and got != self.fingerprint:
            raise ValueError(
                f"out: {self.path!r} holds a different campaign (another model, sample, n, key, times, "
                f"tolerances or chunk size); remove it or choose another path"
            )

    def done(self) -> set[int]:
        if self.zarr:
            if not os.path.exists(self.path):
                return set()
            import zarr

            group = zarr.open_group(self.path, mode="r")
            self._check(dict(group.attrs))
            if "chunk_done" not in group:
                return set()
            chunk_done = group["chunk_done"]
            assert isinstance(chunk_done, zarr.Array), "write() makes chunk_done an array"
            return {int(i) for i in np.flatnonzero(np.asarray(chunk_done[:]))}
        if os.path.exists(self.path):
            import xarray as xr

            with xr.open_dataset(self.path) as ds:
                self._check(ds.attrs)
            return set(range(self.n_chunks))
        if not os.path.isdir(self.parts):
            return set()
        meta = os.path.join(self.parts, "campaign.json")
        if os.path.exists(meta):
            with open(meta) as fh:
                self._check(json.load(fh))
        return {int(f[6:12]) for f in os.listdir(self.parts) if f.startswith("chunk_") and f.endswith(".nc")}

    def write(self, index: int, ds, template) -> None:
        if self.zarr:
            import zarr

            if not os.path.exists(self.path):
                tmp = self.path + f".tmp{os.getpid()}"
                shutil.rmtree(tmp, ignore_errors=True)
                template = template.assign(chunk_done=(("chunk",), np.zeros(self.n_chunks, bool)))
                template.attrs.update(self.attrs)
                template.attrs["jaxtree_campaign"] = self.fingerprint
                template.to_zarr(tmp, mode="w", compute=False, consolidated=False, zarr_format=2)
                os.replace(tmp, self.path)
            region = {"run": slice(int(ds.run[0]), int(ds.run[-1]) + 1)}
            ds.drop_vars([v for v in ds.coords if "run" not in ds[v].dims]).to_zarr(
                self.path, region=region, consolidated=False
            )
            chunk_done = zarr.open_group(self.path, mode="r+")["chunk_done"]
            assert isinstance(chunk_done, zarr.Array), "made an array with the template above"
            chunk_done[index] = True
            return

        os.makedirs(self.parts, exist_ok=True)
        meta = os.path.join(self.parts, "campaign.json")
        if not os.path.exists(meta):
            with atomic_write(meta, "w") as fh:
                json.dump({"jaxtree_campaign": self.fingerprint}, fh)
        final = os.path.join(self.parts, f"chunk_{index:06d}.nc")
        tmp = final + f".tmp{os.getpid()}"
        ds.to_netcdf(tmp)
        os.replace(tmp, final)

    def read(self):
        import xarray as xr

        if self.zarr:  # read lazily: a campaign larger than memory stays on disk until read
            ds = xr.open_zarr(self.path, consolidated=False, chunks=None)
            return ds.drop_vars("chunk_done")
        if os.path.exists(self.path):
            return xr.load_dataset(self.path)
        files = sorted(
            os.path.join(self.parts, f) for f in os.listdir(self.parts) if f.startswith("chunk_") and f.endswith(".nc")
        )
        ds = xr.concat(
            [xr.load_dataset(f) for f in files],
            dim="run",
            data_vars="minimal",
            coords="minimal",
            compat="override",
            join="override",
        )
        tmp = self.path + f".tmp{os.getpid()}"
        ds.attrs.update(self.attrs)
        ds.attrs["jaxtree_campaign"] = self.fingerprint
        ds.to_netcdf(tmp)
        os.replace(tmp, self.path)
        shutil.rmtree(self.parts, ignore_errors=True)
        return ds


def fingerprint(models, ts, t1, rtol, atol, cfg, chunk_size) -> str:
    h = hashlib.sha256()
    for leaf in jax.tree_util.tree_leaves(models):
        if eqx.is_array(leaf):
            h.update(np.ascontiguousarray(np.asarray(leaf)).tobytes())
    h.update(
        repr(
            (
                np.asarray(ts).tolist(),
                float(t1),
                float(rtol),
                float(atol),
                tuple(cfg),
                chunk_size,
                str(jax.tree_util.tree_structure(models)),
            )
        ).encode()
    )
    return h.hexdigest()[:32]


def template(ds, n):
    """A lazily filled dataset of the whole campaign's shape (for the Zarr store's layout)."""
    import xarray as xr

    size = ds.sizes["run"]
    reps = -(-n // size)
    full = xr.concat(
        [ds] * reps, dim="run", data_vars="minimal", coords="minimal", compat="override", join="override"
    ).isel(run=slice(0, n))
    return full.assign_coords(run=np.arange(n)).chunk({"run": size})
