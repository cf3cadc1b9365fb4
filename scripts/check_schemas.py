"""Validates TOML files against the JSON Schemas `robodeploy schema` writes, with the independent
`jsonschema` package (draft 2020-12), so a shipped robot.toml, manifest or mirror file that the
schema would reject in a user's editor is found here first.

Usage: check_schemas.py SCHEMA.json FILE.toml [FILE.toml ...]   (exit 1 when any file fails)
Each file prints `ok <file>` or `FAIL <file>: <field path>: <message>` per error.
"""
import json
import sys
import tomllib

import jsonschema


def main() -> int:
    if len(sys.argv) < 3:
        print(__doc__, file=sys.stderr)
        return 2
    with open(sys.argv[1], encoding="utf-8") as f:
        schema = json.load(f)
    jsonschema.Draft202012Validator.check_schema(schema)
    validator = jsonschema.Draft202012Validator(schema)
    failed = False
    for path in sys.argv[2:]:
        with open(path, "rb") as f:
            doc = tomllib.load(f)
        errors = sorted(validator.iter_errors(doc), key=lambda e: list(e.absolute_path))
        for e in errors:
            where = ".".join(str(p) for p in e.absolute_path) or "(top level)"
            print(f"FAIL {path}: {where}: {e.message}")
        if errors:
            failed = True
        else:
            print(f"ok {path}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
