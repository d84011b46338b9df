"""Security of a swarm's Zenoh network (docs/security.md).

* :mod:`~swarmnet.security.identity`: who a certificate speaks for (``uav-3.alpha``, ...);
* :mod:`~swarmnet.security.roster`: the swarm's members and revocations (``roster.json``);
* :mod:`~swarmnet.security.pki`: the swarm's CA and key directory (``mrswarm keys``; the only
  module that imports ``cryptography``);
* :mod:`~swarmnet.security.acl`: Zenoh access control generated from the roster;
* :mod:`~swarmnet.security.credentials`: a node's credentials and its secured Zenoh configuration;
* :mod:`~swarmnet.security.links`, :mod:`~swarmnet.security.zenoh_log`: what is refused, counted.
"""
