"""Who may do what on a secured lab network: the lab's identities and the router's ACL.

Every process of a secured lab speaks with a certificate whose common name is its identity, and
the router's access-control list (deny by default) is derived from the contract
(`services.core.contract`): an identity may put exactly the keys whose publishers include one
of its services (not those only ever queried), declare liveliness tokens only for its own
services, and answer queries only on the queryable keys of its services (the contract's
`queried_only`, or "queryable" in its rate). Every identity belongs to the rigs it serves and
touches only their keys (`nod/<rig>/…`): the router forwards it nothing of another rig, and
refuses whatever it puts, declares or answers there. The kinds of identity:

- a **host role** of a rig (`control`, `camera`, `arm`, `eyes`): the services of that host.
  Each may also engage its rig's e-stop (`safety/estop`: stopping is always safe); only
  `control` runs `nod estop`'s release, so only it may put its rig's `safety/release`.
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

A lab of several rigs (`nod lab secure --rigs rig1,rig2`) has these identities per rig, named
`<rig>.<identity>` (a rig name has no dot, so no two collide), and two lab-wide ones that serve
every rig: `lab.monitor`, the monitor's rights on every rig (`nod lab status`, a lab screen),
and `lab.estop`, `nod estop`'s rights on every rig — it engages and, as the contract lets
`nod estop` do, releases any rig's e-stop, and nothing else.

The router's own session (`nod router`, the control station's `nod up`) is inside the
boundary: zenoh applies the ACL to its network faces, not to the router process itself.

A lab with a router per rig (`--router-per-rig`) has two kinds of router, each with its own ACL.
Zenoh applies a router's ACL to every face, a router's link as much as a client's, and matches
the far router's certificate name on both sides of the TLS link; so each link is an identity:

- a **rig router** (`rig_router_acl`) admits its rig's identities as above, the lab's monitor and
  e-stop with their rights on this rig only (so a rig can be watched and stopped with the lab's
  identities when the lab router is down), and the lab router (`lab.router`) with no more than
  those two have on this rig: the router forwards it nothing of another rig, and takes from it
  only the lab identities' puts, tokens and answers on this rig.
- the **lab router** (`lab_router_acl`) admits the lab's monitor and e-stop (every rig) and each
  rig router (`<rig>.router`) with the union of its rig's identities' rights on its own rig: a
  compromised or misconfigured rig1 router can put, declare and answer nothing in rig2, and is
  forwarded nothing of it. A rig's own hosts are not admitted there: they reach their router.

Declarations of interest (subscribers, liveliness subscribers and queries) whose rig chunk is a
wildcard (`nod/*/…`, the lab view's) are admitted from the lab's side on every router: they carry
no data, and what is delivered for them stays within the rig (`deliver`).
"""

from __future__ import annotations

from dataclasses import dataclass

from services.core.contract import TOPICS

ALL_MESSAGES = (
    "put",
    "delete",
    "declare_subscriber",
    "query",
    "reply",
    "declare_queryable",
    "liveliness_token",
    "declare_liveliness_subscriber",
    "liveliness_query",
)
LAUNCHER = "launcher"  # the contract's name of a `nod up` process
MONITOR = "monitor"
ESTOP = "estop"  # the contract's name of `nod estop`
LAB = "lab"  # the lab-wide identities' folder and name prefix: no rig may be called so
ROUTER = "router"  # a router's folder and name (`<rig>.router`, `lab.router`)
EVERY_RIG = "*"  # the rig chunk of a lab-wide identity's keys: any rig on the lab's router


@dataclass(frozen=True)
class Identity:
    """One certificate of the lab and what its holder may do."""

    name: str  # the certificate's common name: what the ACL matches
    services: tuple[str, ...]  # the contract's publishers it speaks for
    folder: str  # where its files are, relative to the `nod lab secure` folder
    rigs: tuple[str, ...]  # the rigs whose keys it may touch
    engages_estop: bool = False  # may put safety/estop though none of its services does

    def _own(self) -> list[str]:
        return sorted(t.name for t in TOPICS.values() if set(t.publishers) & set(self.services))

    def publishes(self) -> list[str]:
        """The topics it may put: those the contract gives to one of its services."""
        own = [t for t in self._own() if not TOPICS[t].queried_only]
        return sorted({*own, "safety/estop"}) if self.engages_estop else own

    def answers(self) -> list[str]:
        """The topics of its services that are queried (the layout, the e-stop latch)."""
        return [t for t in self._own() if TOPICS[t].queried_only or "queryable" in TOPICS[t].rate]


# The hosts of a lab and the services of each. `nod up` runs as the host's launcher identity,
# `nod monitor` as the monitor identity, everything else as the host's role.
HOSTS: dict[str, tuple[str, ...]] = {
    # The participant-facing services (speaker, display) and the LSL outlet sit by the control
    # station: only a liveliness token and a heartbeat of their own to put.
    "control": ("experiment", "operator", ESTOP, "run", "record", "speaker", "display", "lsl"),
    "camera": ("vision", "sim"),
    "arm": ("decision", "actuation"),
    "eyes": ("eyes",),
}


def _named(rig: str, name: str, folder: str, lab: bool) -> tuple[str, str]:
    """An identity's common name and folder: bare for a single rig, under its rig in a lab."""
    return (f"{rig}.{name}", f"{rig}/{folder}") if lab else (name, folder)


def host_identity(role: str, rig: str, lab: bool = False) -> Identity:
    """A host's identity: its services' keys, and the e-stop's engage, on its rig."""
    name, folder = _named(rig, role, role, lab)
    return Identity(name, HOSTS[role], folder, (rig,), engages_estop=True)


def launcher_identity(role: str, rig: str, lab: bool = False) -> Identity:
    """The identity of `nod up` on a host: rig events and its heartbeat, nothing else."""
    name, folder = _named(rig, f"{role}-{LAUNCHER}", f"{role}/{LAUNCHER}", lab)
    return Identity(name, (LAUNCHER,), folder, (rig,))


def monitor_identity(rig: str, lab: bool = False) -> Identity:
    """The read-only identity of one rig's monitors and screens."""
    name, folder = _named(rig, MONITOR, MONITOR, lab)
    return Identity(name, (MONITOR,), folder, (rig,))


def identities(roles: list[str], rig: str) -> list[Identity]:
    """Every identity a single rig of these host roles needs (bare names: `control`, …).

    Each role, its launcher, the monitor.
    """
    out = [f(r, rig) for r in roles for f in (host_identity, launcher_identity)]
    return [*out, monitor_identity(rig)]


def lab_identities(roles: list[str], rigs: list[str]) -> list[Identity]:
    """Every identity of a lab of several rigs (`rig1.control`, …, `lab.estop`).

    Each rig's, under its name, and the lab's monitor and e-stop, which serve every rig.
    """
    out = [
        f(r, rig, True) for rig in rigs for r in roles for f in (host_identity, launcher_identity)
    ]
    out += [monitor_identity(rig, True) for rig in rigs]
    return [
        *out,
        Identity(f"{LAB}.{MONITOR}", (MONITOR,), f"{LAB}/{MONITOR}", (EVERY_RIG,)),
        Identity(f"{LAB}.{ESTOP}", (ESTOP,), f"{LAB}/{ESTOP}", (EVERY_RIG,)),
    ]


def rig_router_identity(rig: str, ids: list[Identity]) -> Identity:
    """A rig's router as the lab router sees it: what its rig's identities may do, there only.

    `ids` are the identities the rig router admits (its rig's and the lab's on it).
    """
    services = sorted({s for ident in ids for s in ident.services})
    return Identity(
        f"{rig}.{ROUTER}", tuple(services), f"{rig}/{ROUTER}", (rig,), engages_estop=True
    )


def rig_router_acl(roles: list[str], rig: str) -> dict:
    """A rig router's access_control: its rig's identities, the lab's on it, the lab router."""
    own = [f(r, rig, True) for r in roles for f in (host_identity, launcher_identity)]
    lab = [
        Identity(f"{LAB}.{MONITOR}", (MONITOR,), f"{LAB}/{MONITOR}", (rig,)),
        Identity(f"{LAB}.{ESTOP}", (ESTOP,), f"{LAB}/{ESTOP}", (rig,)),
    ]
    # The lab router speaks for the lab's identities: their rights on this rig, no more.
    upstream = Identity(f"{LAB}.{ROUTER}", (MONITOR, ESTOP), ROUTER, (rig,))
    doc = acl([*own, monitor_identity(rig, True), *lab, upstream])
    _observe_every_rig(doc, [i.name for i in (*lab, upstream)])
    return doc


def lab_router_acl(roles: list[str], rigs: list[str]) -> dict:
    """The lab router's access_control: the lab's identities and one rig router per rig."""
    lab = lab_identities(roles, rigs)[-2:]  # lab.monitor, lab.estop
    routers = []
    for rig in rigs:
        own = [f(r, rig, True) for r in roles for f in (host_identity, launcher_identity)]
        routers.append(rig_router_identity(rig, [*own, monitor_identity(rig, True), *lab]))
    return acl([*lab, *routers])


def _observe_every_rig(doc: dict, names: list[str]) -> None:
    """Let `names` declare interest in every rig at once (`nod/*/…`): delivery stays `deliver`'s."""
    doc["rules"].append(
        _rule(
            "observe:every-rig",
            ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query", "query"],
            [f"nod/{EVERY_RIG}/**"],
        )
    )
    for policy in doc["policies"]:
        if policy["id"] in names:
            policy["rules"].append("observe:every-rig")


def _rule(rule_id: str, messages: list[str], keys: list[str], flow: str = "ingress") -> dict:
    return {
        "id": rule_id,
        "permission": "allow",
        "flows": [flow],
        "messages": messages,
        "key_exprs": keys,
    }


def acl(ids: list[Identity]) -> dict:
    """The router's access_control section: deny by default, allow what each identity needs."""
    rigs = sorted({r for ident in ids for r in ident.rigs})
    # zenoh's ACL admits a declaration only inside an allowed key expression, and a client puts
    # only what it knows someone subscribes to: the router tells every face of every
    # subscription in the lab (who listens is no secret), or a rig's camera would never send to
    # the lab view's `nod/*/rig/status`. The samples themselves go only where `deliver` allows.
    rules: list[dict] = [
        _rule(
            "interest",
            ["declare_subscriber", "declare_liveliness_subscriber"],
            ["nod/**"],
            flow="egress",
        ),
    ]
    for rig in rigs:
        ns = f"nod/{rig}"
        rules += [
            # What the router may forward to an identity of the rig: everything of the rig.
            _rule(f"deliver:{rig}", list(ALL_MESSAGES), [f"{ns}/**"], flow="egress"),
            # Every identity may listen to its rig, see who is alive, and query (the layout,
            # the latch).
            _rule(
                f"observe:{rig}",
                [
                    "declare_subscriber",
                    "declare_liveliness_subscriber",
                    "liveliness_query",
                    "query",
                ],
                [f"{ns}/**"],
            ),
        ]
    subjects, policies = [], []
    for ident in ids:
        n = ident.name

        def keys(names: list[str], ident: Identity = ident) -> list[str]:
            return [f"nod/{rig}/{k}" for rig in ident.rigs for k in names]

        rules.append(_rule(f"{n}-publish", ["put"], keys(ident.publishes()) or keys(["-none-"])))
        rules.append(
            # Its services' tokens, and their claims (`services.core.claim`: one conductor).
            _rule(f"{n}-alive", ["liveliness_token"], keys(
                [k for s in ident.services for k in (f"alive/{s}", f"alive/{s}/claim/*")]))
        )
        names = [f"{n}-publish", f"{n}-alive", "interest"]
        names += [f"{what}:{rig}" for rig in ident.rigs for what in ("deliver", "observe")]
        if ident.answers():
            rules.append(
                _rule(f"{n}-answer", ["declare_queryable", "reply"], keys(ident.answers()))
            )
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
