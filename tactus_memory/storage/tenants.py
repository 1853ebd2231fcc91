"""Tenants: the walls between the teams that share one store.

A tenant is a plain name matching the session-id pattern (``limits.ID_PATTERN``). Each
tenant's memory is its own LanceDB database: the default tenant's is the store's root (so a
store made before tenants existed is the default tenant's, unchanged), any other tenant's is
``<root>/tenants/<name>`` (a folder, or an object-storage prefix). Nothing a tenant's
connection runs can name another tenant's tables, so no filter, id or count reaches across
(README "Keys and tenants"). The key and audit tables live in the root database, beside the
default tenant's tables (:mod:`tactus_memory.storage.keys`).
"""

from __future__ import annotations

from collections.abc import Iterable

from tactus_memory.limits import ID_RE
from tactus_memory.storage.connect import normalise_uri
from tactus_memory.storage.where import validate_id

#: the tenant of a store without keys, of the operator's ``--token``, and of
#: ``Memory.open(path)`` without ``tenant=``
DEFAULT_TENANT = "default"
#: where the non-default tenants' databases live, under the store's root
TENANTS_DIR = "tenants"


def validate_tenant(value: object) -> str:
    """A tenant name: 1-128 characters of ``[A-Za-z0-9._:-]`` (InvalidIdError otherwise)."""
    return validate_id(value, "tenant")


def tenant_uri(root: str, tenant: str = DEFAULT_TENANT) -> str:
    """The location of ``tenant``'s database in the store at ``root`` (a path or URI)."""
    root = normalise_uri(str(root))
    tenant = validate_tenant(tenant)
    if tenant == DEFAULT_TENANT:
        return root
    return f"{root.rstrip('/')}/{TENANTS_DIR}/{tenant}"


def tenant_names(root: str, named: Iterable[str] = ()) -> list[str]:
    """The tenants of the store at ``root``, default first: the default tenant, each folder
    under ``tenants/`` (local stores), and ``named`` (the tenants its keys name: on object
    storage, a tenant without keys is found by no listing)."""
    import os

    root = normalise_uri(str(root))
    names = {DEFAULT_TENANT, *map(validate_tenant, named)}
    folder = os.path.join(root, TENANTS_DIR)
    if "://" not in root and os.path.isdir(folder):
        names.update(n for n in os.listdir(folder) if ID_RE.fullmatch(n))
    return [DEFAULT_TENANT, *sorted(names - {DEFAULT_TENANT})]
