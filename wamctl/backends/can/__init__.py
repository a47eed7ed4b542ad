"""The real WAM over CAN (python-can): the backend (:mod:`.backend`), Barrett's puck protocol (:mod:`.protocol`:
ids, groups, properties, packed positions and torques) and simulated pucks for tests (:mod:`.puck_sim`).
"""
