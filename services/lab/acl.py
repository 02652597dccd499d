"""Who may do what on a secured lab network: the lab's identities and the router's ACL.

Every process of a secured lab speaks with a certificate whose common name is its identity, and
the router's access-control list (deny by default) is derived from the contract
(`services.core.contract`): an identity may put exactly the keys whose publishers include one
of its services (not those only ever queried), declare liveliness tokens only for its own
services, and answer queries only on the queryable keys of its services (the contract's
`queried_only`, or "queryable" in its rate). Three kinds of identity:

- a **host role** (`control`, `camera`, `arm`, `eyes`): the services of that host. Each may also
  engage the e-stop (`safety/estop`: stopping is always safe); only `control` runs `nod estop`'s
  release, so only it may put `safety/release`.
- a **launcher** per host role (`<role>-launcher`): `nod up`'s own session, the only publisher
  of `rig/event` in the contract, so the only identity that may put it (a host's services
  cannot forge the launchers' account of what died and restarted). It engages nothing.
- **`monitor`**: read-only, for `nod monitor`, `nod status` and lab screens. It may subscribe to
  and query every key of the rig and see who is alive, declare only `alive/monitor` and put only
  its `rig/status` heartbeat (the contract's one key with the monitor among its publishers). It
  may not engage the e-stop either: a lab screen is the identity handed to machines that are
  not part of the rig (a wall screen, a visitor's laptop, a web viewer); an engage there would
  interrupt the trial under way and need the control station to release it, and nothing the
  monitor runs ever engages one. Stopping stays with every rig host and the hardware e-stop.

The router's own session (the control station's `nod up` or `nod router`) is inside the
boundary: zenoh applies the ACL to its network faces, not to the router process itself.
"""

from __future__ import annotations

from dataclasses import dataclass

from services.core.contract import TOPICS

ALL_MESSAGES = (
    "put", "delete", "declare_subscriber", "query", "reply", "declare_queryable",
    "liveliness_token", "declare_liveliness_subscriber", "liveliness_query",
)
LAUNCHER = "launcher"  # the contract's name of a `nod up` process
MONITOR = "monitor"


@dataclass(frozen=True)
class Identity:
    """One certificate of the lab and what its holder may do."""

    name: str  # the certificate's common name: what the ACL matches
    services: tuple[str, ...]  # the contract's publishers it speaks for
    folder: str  # where its files are, relative to the `nod lab secure` folder
    engages_estop: bool = False  # may put safety/estop

    def _own(self) -> list[str]:
        return sorted(t.name for t in TOPICS.values() if set(t.publishers) & set(self.services))

    def publishes(self) -> list[str]:
        """The topics it may put: those the contract gives to one of its services."""
        return [t for t in self._own() if not TOPICS[t].queried_only]

    def answers(self) -> list[str]:
        """The topics of its services that are queried (the layout, the e-stop latch)."""
        return [t for t in self._own() if TOPICS[t].queried_only or "queryable" in TOPICS[t].rate]


# The hosts of a lab and the services of each. `nod up` runs as the host's launcher identity,
# `nod monitor` as the monitor identity, everything else as the host's role.
HOSTS: dict[str, tuple[str, ...]] = {
    "control": ("experiment", "operator", "estop", "run", "record"),
    "camera": ("vision", "sim"),
    "arm": ("decision", "actuation"),
    "eyes": ("eyes",),
}


def host_identity(role: str) -> Identity:
    """A host's identity: its services' keys, and the e-stop's engage."""
    return Identity(role, HOSTS[role], role, engages_estop=True)


def launcher_identity(role: str) -> Identity:
    """The identity of `nod up` on a host: rig events and its heartbeat, nothing else."""
    return Identity(f"{role}-{LAUNCHER}", (LAUNCHER,), f"{role}/{LAUNCHER}")


def monitor_identity() -> Identity:
    """The read-only identity of monitors and lab screens."""
    return Identity(MONITOR, (MONITOR,), MONITOR)


def identities(roles: list[str]) -> list[Identity]:
    """Every identity a lab of these host roles needs: each role, its launcher, the monitor."""
    out = [f(r) for r in roles for f in (host_identity, launcher_identity)]
    return [*out, monitor_identity()]


def _rule(rule_id: str, messages: list[str], keys: list[str], flow: str = "ingress") -> dict:
    return {
        "id": rule_id, "permission": "allow", "flows": [flow], "messages": messages,
        "key_exprs": keys,
    }


def acl(rig: str, ids: list[Identity]) -> dict:
    """The router's access_control section: deny by default, allow what each identity needs."""
    ns = f"nod/{rig}"
    rules: list[dict] = [
        # What the router may forward to any authenticated identity: everything of the rig.
        _rule("deliver", list(ALL_MESSAGES), [f"{ns}/**"], flow="egress"),
        # Every identity may listen, see who is alive, and query (the layout, the latch).
        _rule("observe", ["declare_subscriber", "declare_liveliness_subscriber",
                          "liveliness_query", "query"], [f"{ns}/**"]),
        _rule("engage-estop", ["put"], [f"{ns}/safety/estop"]),
    ]
    subjects, policies = [], []
    for ident in ids:
        n = ident.name
        rules.append(_rule(f"{n}-publish", ["put"],
                           [f"{ns}/{t}" for t in ident.publishes()] or [f"{ns}/-none-"]))
        rules.append(_rule(f"{n}-alive", ["liveliness_token"],
                           [f"{ns}/alive/{s}" for s in ident.services]))
        names = [f"{n}-publish", f"{n}-alive", "deliver", "observe"]
        if ident.engages_estop:
            names.append("engage-estop")
        if ident.answers():
            rules.append(_rule(f"{n}-answer", ["declare_queryable", "reply"],
                               [f"{ns}/{t}" for t in ident.answers()]))
            names.append(f"{n}-answer")
        subjects.append({"id": n, "cert_common_names": [n]})
        policies.append({"id": n, "rules": names, "subjects": [n]})
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }
