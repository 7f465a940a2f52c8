"""Ray's token, checked before Ray starts or is joined, however it is given.

Ray reads its token from the first of ``RAY_AUTH_TOKEN`` (the token itself),
``RAY_AUTH_TOKEN_PATH`` (a file) and ``~/.ray/auth_token`` that is set or present; anyone
who reads it can run code as the user on every process of that Ray. So the promise is the
same for each way: the token is there, and only its owner can read it, or the command stops
with one line before Ray starts.

- ``RAY_AUTH_TOKEN``: set and not empty (an environment is readable by its user alone).
- ``RAY_AUTH_TOKEN_PATH``: a file of the user's, holding a token, that no other user may
  read or write (mode 0600 or stricter); anything else is refused, never changed: the file
  was named by the user, and may be shared on purpose.
- ``~/.ray/auth_token``: the file this program makes for a local Ray (a new random token,
  mode 0600) when there is none, and makes 0600, with a warning, when other users can read
  it (Ray itself would write it readable by every user).

A local Ray must use token authentication (``RAY_AUTH_MODE`` other than ``token`` is
refused: processes that run any code they are sent listen on loopback, where every user of
the machine reaches them). Joining a cluster checks the token it would send, and makes no
file: the cluster's own token is the one that works there.
"""

from __future__ import annotations

import os
import stat
import tempfile
import warnings
from pathlib import Path

from plantdreamer.errors import InputError

RAY_AUTH_MODE_ENV = "RAY_AUTH_MODE"
TOKEN_ENV = "RAY_AUTH_TOKEN"
TOKEN_PATH_ENV = "RAY_AUTH_TOKEN_PATH"
CHOOSE_RAY = (
    "start Ray yourself (e.g. `ray start --head --node-ip-address 127.0.0.1`) and pass "
    "--address to use it as it is"
)


def default_token_path() -> Path:
    return Path.home() / ".ray" / "auth_token"


def check_token(local: bool) -> None:
    """The token Ray will read is present and private (see the module docstring);
    ``local``: for a Ray this command starts, which must use it (and may get the default
    file made)."""
    mode = os.environ.get(RAY_AUTH_MODE_ENV)
    if local and mode is not None and mode.lower() != "token":
        raise InputError(
            f"{RAY_AUTH_MODE_ENV}={mode} would start the local Ray without token "
            "authentication (any user of this machine could run code as you); unset it or "
            f"set {RAY_AUTH_MODE_ENV}=token, or {CHOOSE_RAY}"
        )
    token = os.environ.get(TOKEN_ENV)
    if token is not None:
        if not token.strip():
            raise InputError(
                f"{TOKEN_ENV} is set but empty, so Ray would have no token; give the token "
                "or unset it"
            )
        return
    named = os.environ.get(TOKEN_PATH_ENV)
    if named is not None:
        check_named_token(named)
        return
    if local:
        private_token(default_token_path())
    elif default_token_path().exists():
        private_token(default_token_path())


def check_named_token(named: str) -> None:
    """``RAY_AUTH_TOKEN_PATH``'s file: the user's own, present, holding a token, and
    neither readable nor writable by any other user."""
    where = f"{TOKEN_PATH_ENV}={named}"
    if not named.strip():
        raise InputError(f"{TOKEN_PATH_ENV} is set but empty; name the token file or unset it")
    path = Path(named).expanduser()
    try:
        info = path.stat()
    except FileNotFoundError:
        raise InputError(
            f"{where}: no such file, so Ray would have no token; write the token there "
            "(readable by you alone: chmod 600) or unset it"
        ) from None
    except OSError as exc:
        raise InputError(f"{where}: cannot read it ({exc.strerror})") from None
    if not stat.S_ISREG(info.st_mode):
        raise InputError(f"{where}: not a file; name the file that holds Ray's token")
    if info.st_uid != os.getuid():
        raise InputError(
            f"{where}: the file belongs to another user, who can read the token that runs "
            "code as you; use a token file of your own (chmod 600)"
        )
    mode = stat.S_IMODE(info.st_mode)
    if mode & 0o077:
        raise InputError(
            f"{where}: other users can read or change it (mode {mode:o}), and whoever reads "
            f"the token can run code as you on this Ray; `chmod 600 {path}` or use another file"
        )
    try:
        text = path.read_text().strip()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{where}: cannot read the token ({exc})") from None
    if not text:
        raise InputError(f"{where}: the file is empty; write Ray's token in it")


def private_token(path: Path) -> None:
    """Makes Ray's token file at ``path`` (a new random token, mode 0600) unless it exists;
    one that other users can read is made 0600, with a warning."""
    if path.exists():
        mode = stat.S_IMODE(path.stat().st_mode)
        if mode & 0o077:
            path.chmod(0o600)
            warnings.warn(
                f"the Ray token file {path} was readable by other users (mode {mode:o}); "
                "made it 0600",
                stacklevel=2,
            )
        return
    import secrets

    path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(prefix=".auth_token.", dir=path.parent)  # mode 0600
    try:
        with os.fdopen(fd, "w") as f:
            f.write(secrets.token_hex(32))  # Ray's own kind of token: 256 random bits
            f.flush()
            os.fsync(f.fileno())
        os.link(name, path)  # never over a token another start wrote meanwhile
    except FileExistsError:
        pass
    finally:
        os.unlink(name)
