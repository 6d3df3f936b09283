"""The whole product: refine, demo, experiment, report. Imports every stage; no stage imports it."""
