"""Monte-Carlo replay campaigns: perturbed lockstep replays of missions, run on Dask.

`perturb` samples what each run flies with, `runner` executes runs (one Dask task per replay)
and keeps their results on disk, `report` turns the results into a table, JSON and HTML.
"""
