"""Deployment: fly a controller on a Crazyflie through cflib (``link`` is the only cflib importer),
or against the simulated Crazyflie (``deploy.sim``) that speaks the real radio protocol over UDP."""
