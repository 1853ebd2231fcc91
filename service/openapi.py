"""The OpenAPI document says what THIS server enforces.

Some limits depend on the memory the app serves, so :func:`install_openapi` patches the
generated schema once per app:

* vector lengths: ``POST /sessions/{id}/vectors`` (each vector) and ``POST /search/like``
  (``vector``) take exactly the space's dimension D; ``POST /senses`` takes ``dim = D``;
  their examples use D;
* ``POST /sessions/{id}/image`` is left out of the document when the space has no vision
  (the route still answers, with a 400 naming the capability);
* every operation documents 400 (a body that is not decodable JSON / a bad
  ``Content-Length``) and 503 (the store cannot be read, or is read-only for writes).

Cross-field rules JSON Schema cannot state are written in the descriptions: ``t_end >= t``,
``after <= before``, and as many ``t`` (``t_end``, ``ids``) entries as vectors or windows.
"""

from __future__ import annotations

import math
from typing import Any

from fastapi import FastAPI
from fastapi.openapi.utils import get_openapi

from tactus_memory.service.problems import problem_responses

IMAGE_PATH = "/sessions/{session}/image"
#: writes that take an explicit item id: 409 when it belongs to another session or sense
ID_WRITES = (
    *(f"/sessions/{{session}}/{kind}" for kind in ("text", "vectors", "image", "touch")),
    "/sessions/{session}/senses/{sense}/windows",
)


def _array_of(node: dict[str, Any]) -> dict[str, Any] | None:
    """The array schema inside ``node`` (``anyOf: [array, null]`` or the array itself)."""
    if node.get("type") == "array":
        return node
    for alt in node.get("anyOf", ()):
        if alt.get("type") == "array":
            return alt
    return None


def patch_schema(doc: dict[str, Any], dim: int, has_vision: bool) -> dict[str, Any]:
    schemas = doc.get("components", {}).get("schemas", {})
    example_vector = [round(1.0 / math.sqrt(dim), 6)] * dim
    vectors = schemas.get("VectorsIn", {})
    if vectors:
        items = vectors["properties"]["vectors"]["items"]
        items["minItems"] = items["maxItems"] = dim
        vectors["examples"] = [
            {"sense": "motion", "vectors": [example_vector], "t": [4.0], "t_end": [5.0]}
        ]
    like = schemas.get("SearchLikeIn", {})
    if like:
        arr = _array_of(like["properties"]["vector"])
        if arr is not None:
            arr["minItems"] = arr["maxItems"] = dim
    sense_in = schemas.get("SenseIn", {})
    if sense_in:
        sense_in["properties"]["dim"]["minimum"] = dim
        sense_in["properties"]["dim"]["maximum"] = dim
        sense_in["examples"] = [
            {"name": "motion", "dim": dim, "encoder": "imu-tcn", "version": "1.2"}
        ]
    if not has_vision:
        doc.get("paths", {}).pop(IMAGE_PATH, None)
    for path, path_item in doc.get("paths", {}).items():
        for method, op in path_item.items():
            responses = op.setdefault("responses", {})
            statuses = (400, 503, 409) if method == "post" and path in ID_WRITES else (400, 503)
            for status, spec in problem_responses(*statuses).items():
                responses.setdefault(
                    str(status),
                    {
                        "description": spec["description"],
                        "content": {
                            "application/problem+json": {
                                "schema": {"$ref": "#/components/schemas/Problem"}
                            }
                        },
                    },
                )
    return doc


def install_openapi(app: FastAPI, dim: int, has_vision: bool) -> None:
    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            doc = get_openapi(
                title=app.title,
                version=app.version,
                description=app.description,
                routes=app.routes,
            )
            app.openapi_schema = patch_schema(doc, dim, has_vision)
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]
