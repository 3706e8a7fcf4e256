"""``python -m pvtflow.service.api``: the schemas section of docs/API.md."""

from pvtflow.service.api.schema_doc import schema_document

print(schema_document())
