"""``/v1/jobs/{id}/instances``: records, paging, class filter, validation, tenancy, states."""

from __future__ import annotations

import dataclasses
from typing import get_type_hints

import pytest

from dcseg.io.instance_record import InstanceRecord
from service.schemas import REQUIRED_RECORD_FIELDS, InstancePublic
from tests.service.conftest import AUTH_A, AUTH_B, assert_problem
from tests.service.segmented import instance_records, run_segmented_job, segment_files


@pytest.fixture
def job(client, upload_id) -> str:
    return run_segmented_job(client, upload_id)


def _ids(response) -> list[int]:
    assert response.status_code == 200, response.text
    return [item["id"] for item in response.json()["instances"]]


def test_listing_holds_every_record_with_size_and_links(client, job):
    body = client.get(f"/v1/jobs/{job}/instances", headers=AUTH_A).json()
    expected = {r["id"]: r for r in instance_records()}
    assert [i["id"] for i in body["instances"]] == sorted(expected)
    assert "next_page_token" not in body or body["next_page_token"] is None
    for item in body["instances"]:
        record = expected[item["id"]]
        assert {k: item[k] for k in record} == record
        size = [hi - lo for lo, hi in zip(record["bbox_min"], record["bbox_max"], strict=True)]
        assert item["size"] == pytest.approx(size, abs=1e-5)
        assert item["links"]["self"] == f"/v1/jobs/{job}/instances/{item['id']}"
    import hashlib

    ply = segment_files()["scene_labelled.ply"]
    assert body["scene_sha256"] == hashlib.sha256(ply).hexdigest()


def test_pages_partition_the_listing(client, job):
    url, seen, token, pages = f"/v1/jobs/{job}/instances", [], None, 0
    while True:
        params = {"page_size": 2, **({"page_token": token} if token else {})}
        body = client.get(url, params=params, headers=AUTH_A).json()
        seen += [i["id"] for i in body["instances"]]
        pages += 1
        token = body.get("next_page_token")
        if not token:
            break
    assert seen == [1, 2, 3, 4, 5] and pages == 3


def test_filter_by_class_and_score(client, job):
    url = f"/v1/jobs/{job}/instances"
    assert _ids(client.get(url, params={"label": "chair"}, headers=AUTH_A)) == [1, 3]
    both = client.get(url, params={"label": ["chair", "lamp"]}, headers=AUTH_A)
    assert _ids(both) == [1, 3, 5]
    assert _ids(client.get(url, params={"min_score": 0.5}, headers=AUTH_A)) == [1, 2, 5]
    chairs = client.get(url, params={"label": "chair", "min_score": 0.5}, headers=AUTH_A)
    assert _ids(chairs) == [1]
    # a class of the vocabulary no object has is an empty page, not an error
    assert _ids(client.get(url, params={"label": "table", "min_score": 0.9}, headers=AUTH_A)) == []


def test_filter_paging_keeps_the_filter(client, job):
    url = f"/v1/jobs/{job}/instances"
    first = client.get(url, params={"label": "chair", "page_size": 1}, headers=AUTH_A).json()
    token = first["next_page_token"]
    second = client.get(
        url, params={"label": "chair", "page_size": 1, "page_token": token}, headers=AUTH_A
    )
    assert _ids(second) == [3] and second.json().get("next_page_token") is None
    other = client.get(url, params={"label": "lamp", "page_token": token}, headers=AUTH_A)
    body = assert_problem(other, 400)
    assert body["errors"][0]["path"] == "query.page_token"


@pytest.mark.parametrize(
    ("params", "field"),
    [
        ({"label": "sofa"}, "query.label"),
        ({"page_size": 0}, "query.page_size"),
        ({"page_size": 501}, "query.page_size"),
        ({"min_score": 1.5}, "query.min_score"),
        ({"min_score": "nan"}, "query.min_score"),
        ({"page_size": "many"}, "query.page_size"),
    ],
)
def test_bad_query_parameters_name_the_field(client, job, params, field):
    response = client.get(f"/v1/jobs/{job}/instances", params=params, headers=AUTH_A)
    body = assert_problem(response, 422)
    assert [e["path"] for e in body["errors"]] == [field]


def test_garbage_page_token_is_400(client, job):
    response = client.get(
        f"/v1/jobs/{job}/instances", params={"page_token": "not-a-token"}, headers=AUTH_A
    )
    assert assert_problem(response, 400)["type"].endswith("bad-page-token")


def test_one_instance(client, job):
    item = client.get(f"/v1/jobs/{job}/instances/2", headers=AUTH_A).json()
    record = next(r for r in instance_records() if r["id"] == 2)
    assert item["label"] == "table" and item["score"] == record["score"]
    assert item["bbox_min"] == record["bbox_min"] and item["n_views"] == record["n_views"]
    unlabelled = client.get(f"/v1/jobs/{job}/instances/4", headers=AUTH_A).json()
    assert unlabelled["label"] is None and unlabelled["label_id"] == -1


def test_unknown_instance_and_bad_id(client, job):
    body = assert_problem(client.get(f"/v1/jobs/{job}/instances/99", headers=AUTH_A), 404)
    assert "instance 99" in body["detail"]
    bad = assert_problem(client.get(f"/v1/jobs/{job}/instances/0", headers=AUTH_A), 422)
    assert bad["errors"][0]["path"] == "path.k"
    assert_problem(client.get(f"/v1/jobs/{job}/instances/x", headers=AUTH_A), 422)


def test_tenancy_and_unknown_job(client, job):
    for url in (f"/v1/jobs/{job}/instances", f"/v1/jobs/{job}/instances/1"):
        assert_problem(client.get(url, headers=AUTH_B), 404)
        assert_problem(client.get(url), 401)
    assert_problem(client.get("/v1/jobs/nope/instances", headers=AUTH_A), 404)
    assert_problem(client.get("/v1/jobs/nope/instances/1", headers=AUTH_A), 404)


def test_unfinished_job_is_409(client, upload_id):
    job = client.post("/v1/jobs", json={"upload_id": upload_id}, headers=AUTH_A).json()["id"]
    for url in (f"/v1/jobs/{job}/instances", f"/v1/jobs/{job}/instances/1"):
        body = assert_problem(client.get(url, headers=AUTH_A), 409)
        assert body["job_id"] == job and "queued" in body["detail"]


def test_job_that_segmented_nothing_is_404(client, upload_id):
    job = run_segmented_job(client, upload_id, files={"other.txt": b"x"})
    body = assert_problem(client.get(f"/v1/jobs/{job}/instances", headers=AUTH_A), 404)
    assert body["type"].endswith("no-instances")


def test_the_api_model_takes_every_field_of_the_record():
    """``InstancePublic`` is built from ``InstanceRecord``: a field added to the record is served
    without a second edit, optional unless the API has always required it."""
    hints = get_type_hints(InstanceRecord)
    names = [field.name for field in dataclasses.fields(InstanceRecord)]
    assert set(REQUIRED_RECORD_FIELDS) <= set(names)
    optional = [name for name in names if name not in REQUIRED_RECORD_FIELDS]
    api = InstancePublic.model_fields
    # the order responses have always had: required fields, size, optional ones, links
    assert list(api) == [*REQUIRED_RECORD_FIELDS, "size", *optional, "links"]
    assert "n_views" in optional
    for name in names:
        if name in REQUIRED_RECORD_FIELDS:
            assert api[name].is_required() and api[name].annotation == hints[name]
        else:
            assert api[name].default is None and api[name].annotation == hints[name] | None


def test_records_lacking_an_optional_field_or_with_unknown_ones_are_served():
    record = {k: v for k, v in instance_records()[0].items() if k != "n_views"}
    given = {**record, "size": [0.0, 0.0, 0.0], "links": {"self": "/x"}, "since": 2}
    item = InstancePublic.model_validate(given)
    body = item.model_dump(mode="json")
    assert body["n_views"] is None and body["since"] == 2
    assert {k: body[k] for k in record} == record
