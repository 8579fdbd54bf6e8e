"""Write the ``.env`` that compose.yaml reads: new random passwords for PostgreSQL and the
service's MQTT user, and the operator key the service and the viewer share.

    python3 deploy/make_env.py        # writes .env beside compose.yaml (mode 0600)

It refuses to replace an ``.env`` that exists: PostgreSQL keeps the password of its first start
in its volume, so a new one would lock the service out (remove the volumes with ``docker compose
down -v`` first, which deletes their data, if that is what you want). Standard library only.
"""

from __future__ import annotations

import os
import secrets
import sys
from pathlib import Path

#: what compose.yaml interpolates, and how many random bytes each gets (hex: URL-safe, as the
#: database and MQTT URLs need)
VARIABLES = {"POSTGRES_PASSWORD": 24, "MQTT_PASSWORD": 24, "ADVISOR_OPERATOR_KEY": 32}


def contents() -> str:
    return "".join(f"{name}={secrets.token_hex(n)}\n" for name, n in VARIABLES.items())


def main(argv: list[str]) -> int:
    target = Path(argv[1]) if len(argv) > 1 else Path(__file__).resolve().parents[1] / ".env"
    try:
        fd = os.open(target, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except FileExistsError:
        print(f"{target} exists: kept (see this script's docstring)", file=sys.stderr)
        return 1
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(contents())
    print(f"wrote {target} ({', '.join(VARIABLES)}; mode 0600)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
