"""Test fixtures: what a successful run of the users role leaves on a host."""


def converged(play, host: str) -> None:
    for user in play.data.docker_users:
        play.snapshot.users[user] = [user, "docker"]
