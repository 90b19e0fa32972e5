"""A batched experiment in miniature for the tests: two jobs, one of which fails."""

from evp.batch.jobs import Job
from evp.experiments.batched import Report, Row


def jobs(variant, quick):
    return [Job("ok", "tests.batch.toy_tasks:square", {"x": 3}), Job("broken", "tests.batch.toy_tasks:fail", {"message": "no data"})]


def report(variant, outcomes, quick, out):
    ours = outcomes["ok"].record["square"]
    return Report("Toy", [f"square: {ours}"], [Row("square", {"value": ours}, {"value": 10}, ours < 10)], {"variant": variant})
