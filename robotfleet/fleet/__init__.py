"""The fleet file: reading it (loader), checking it against every setting
(check, registry), the engine's own settings (connection), the editors'
JSON schema (schema)."""
