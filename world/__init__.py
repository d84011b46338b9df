"""The world of an experiment, at the edge: virtual sensors and actuators, hazards, shared airspace (docs/world.md).

- :mod:`.config`: the scenario's ``world:`` section and the service's configuration;
- :mod:`.plume`, :mod:`.fire`, :mod:`.targets`: the models; :mod:`.model`: their state in
  experiment time, and every UAV's virtual tank;
- :mod:`.sensing`: each UAV's readings at their rate and latency;
- :mod:`.airspace`: the traffic feed between swarms;
- :mod:`.service`: the process (``python -m world``, ``mrswarm world``); :mod:`.record`: its files.
"""
