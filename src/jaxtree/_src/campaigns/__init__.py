"""Runs larger than one call: ``campaign`` (Monte Carlo campaigns in vmapped chunks over devices
or a Dask cluster, stored and resumable) and ``chunked`` (one long simulation written to a result
file part by part, resumable after an interruption; its configuration in ``chunked_config``, one
part's run and dataset in ``chunked_parts``).
"""
