"""``python -m service.api``: the schemas section of docs/API.md."""

from service.api.schemas import schema_document

print(schema_document())
