"""``python -m service.api``: the schemas section of docs/API.md."""

from service.api.schema_doc import schema_document

print(schema_document())
