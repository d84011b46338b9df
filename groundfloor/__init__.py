"""The ground floor: what every package of mrswarm stands on, and nothing about swarms.

One copy of each helper the layers above would otherwise write again:

* :mod:`groundfloor.errors`: :class:`~groundfloor.errors.MrswarmError`, the root of every error
  mrswarm raises on purpose, and :class:`~groundfloor.errors.Rejected`, input refused and counted;
* :mod:`groundfloor.process`: a child that dies with its parent, stop signals;
* :mod:`groundfloor.files`: a file replaced atomically (temporary file, rename);
* :mod:`groundfloor.histogram`: the mergeable log-binned histogram of ages and delays;
* :mod:`groundfloor.schema` (with :mod:`~groundfloor.schema_errors`) and :mod:`groundfloor.strict_yaml`:
  typed configuration whose errors name the field, and YAML read strictly;
* :mod:`groundfloor.net`: ``Addr``, a host and port.

It imports no other package of the project, and this file imports none of its modules, so a
UAV process loads only what it uses.
"""
