"""The CLI's one-line summary names objects (instances.json), not clusters, as instances."""

from dcseg.cli.run import summary_line


def test_summary_counts_objects_and_clusters_apart() -> None:
    counts = {"clusters": 70, "labelled_clusters": 26, "instances": 21}
    line = summary_line({"counts": counts, "metrics_summary": None})
    assert line == "21 objects (70 clusters, 26 labelled)"


def test_summary_of_a_run_from_before_the_object_level() -> None:
    line = summary_line({"counts": {"clusters": 5, "labelled_clusters": 2}})
    assert line == "5 clusters, 2 labelled"
