"""Who a request is for: tenant names and the headers that carry a token and a tenant.

Base vocabulary shared by storage (:mod:`tactus_memory.storage.tenants`: one database per
tenant), the service (the bearer token and ``X-Tactus-Tenant``) and the remote client."""

from __future__ import annotations

from tactus_memory.names import validate_id

#: the tenant of a store without keys, of the operator's ``--token``, and of
#: ``Memory.open(path)`` without ``tenant=``
DEFAULT_TENANT = "default"


#: the HTTP header with which the operator's token (not a key) names its tenant
TENANT_HEADER = "x-tactus-tenant"


def validate_tenant(value: object) -> str:
    """A tenant name: 1-128 characters of ``[A-Za-z0-9._:-]`` (InvalidIdError otherwise)."""
    return validate_id(value, "tenant")


def auth_headers(token: str | None, tenant: str | None = None) -> dict[str, str]:
    """The headers a client sends: the bearer ``token`` (none without one) and, for the
    operator's token acting for a tenant, that ``tenant`` (None: no tenant header)."""
    headers = {"Authorization": f"Bearer {token}"} if token else {}
    if tenant is not None:
        headers[TENANT_HEADER] = validate_tenant(tenant)
    return headers
