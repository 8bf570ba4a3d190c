"""What several test modules share (test modules never import each other; fixtures are in
tests/conftest.py):

    stack.py                 the repository, the run configurations of the tests, a headless run,
                             polling (wait_until)
    api.py                   the REST API's test store, users, tokens, and `ares api` as a process
    records.py               checks of the black box's records (every second once)
    gnss.py                  GNSS fixes and the places on Earth the route-import tests drive
    mission.py               the mission manager with the body on the in-memory bus (Tour)
    receiver_logs.py         NMEA logs as real receivers and loggers write them
    random_routes.py         hypothesis strategies for routes and poses along them
    path_match_reference.py  a brute-force path match the KD-tree's is checked against
    lidar_scene.py           a realistic LiDAR frame for the perception tests
"""
