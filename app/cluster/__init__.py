"""Scale-out: gateways in front of map shards (docs/architecture.md "Many devices").

`routing`: which shard serves a session (its live owner, else rendezvous hashing);
`gateway`: the public port, relaying wire protocol v1 to the shards and across their
failures; `shards`: the shards as named, detached Ray actors. A shard is a SemanticXR
server with `shard_name` set (app.server), so this package sits above app.server.
"""
