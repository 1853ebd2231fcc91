"""Tenants: the walls between the teams that share one store.

A tenant is a plain name matching the session-id pattern (``limits.ID_PATTERN``). Each
tenant's memory is its own LanceDB database: the default tenant's is the store's root (so a
store made before tenants existed is the default tenant's, unchanged), any other tenant's is
``<root>/tenants/<name>`` (a folder, or an object-storage prefix). Nothing a tenant's
connection runs can name another tenant's tables, so no filter, id or count reaches across
(README "Keys and tenants"). The key and audit tables live in the root database, beside the
default tenant's tables (:mod:`tactus_memory.storage.keys`).

A tenant comes into being when a key names it (``tactus keys create --tenant NAME``) or when
``Memory.open(path, tenant=NAME)`` writes to it; the server never creates one for a request
(:func:`tenant_exists`: an operator's typo in ``X-Tactus-Tenant`` is a 404, not a new tenant).
"""

from __future__ import annotations

from collections.abc import Iterable

from tactus_memory.identity import DEFAULT_TENANT, validate_tenant
from tactus_memory.limits import ID_RE
from tactus_memory.storage.connect import normalise_uri, storage_options_for

#: where the non-default tenants' databases live, under the store's root
TENANTS_DIR = "tenants"


def tenant_uri(root: str, tenant: str = DEFAULT_TENANT) -> str:
    """The location of ``tenant``'s database in the store at ``root`` (a path or URI)."""
    root = normalise_uri(str(root))
    tenant = validate_tenant(tenant)
    if tenant == DEFAULT_TENANT:
        return root
    return f"{root.rstrip('/')}/{TENANTS_DIR}/{tenant}"


def store_root(uri: str, tenant: str = DEFAULT_TENANT) -> str:
    """The root of the store whose ``tenant`` database is at ``uri`` (the inverse of
    :func:`tenant_uri`): where the store's ``keys`` and ``audit`` tables live."""
    uri = normalise_uri(str(uri)).rstrip("/")
    tenant = validate_tenant(tenant)
    if tenant == DEFAULT_TENANT:
        return uri
    suffix = f"/{TENANTS_DIR}/{tenant}"
    if not uri.endswith(suffix):
        raise ValueError(f"{uri!r} is not the database of tenant {tenant!r} (no {suffix!r})")
    return uri[: -len(suffix)]


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


def tenant_exists(
    root: str,
    tenant: str,
    named: Iterable[str] = (),
    storage_options: dict[str, str] | None = None,
) -> bool:
    """Whether ``tenant`` exists in the store at ``root``: the default tenant always; another
    once a key names it (``named``: the keys' tenants) or its database holds a table."""
    import lancedb

    tenant = validate_tenant(tenant)
    if tenant == DEFAULT_TENANT or tenant in set(named):
        return True
    uri = tenant_uri(root, tenant)
    if "://" not in uri:
        import os

        if not os.path.isdir(uri):
            return False  # (lancedb.connect would create the folder)
    options = storage_options_for(uri, storage_options)
    res = lancedb.connect(uri, storage_options=options or None).list_tables()
    return bool(list(getattr(res, "tables", res)))
