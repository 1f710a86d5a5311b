"""MAVLink for the simulated vehicle: fly it from PX4 or ArduPilot SITL, watch it from a ground station.

Pure Python (pymavlink, numpy), no rclpy: :mod:`multirotor_ros.nodes.mavlink_bridge` is the ROS
wrapper. Frames are NED / FRD on the wire and ENU / FLU inside; every conversion goes through
:mod:`multirotor_ros.frames` (:func:`.messages.ned_view` applies it to a whole state).

Modules
    :mod:`.wire` codec and sockets (refusals counted by :mod:`multirotor_ros.refusals`);
    :mod:`.signing` MAVLink 2 signing policy;
    :mod:`.sensors` barometer (ISA), magnetometer and GPS synthesis around a home;
    :mod:`.motor_order` which output drives which rotor, from the geometry and the stacks' numbering;
    :mod:`.actuators` actuator outputs -> rotor speeds through the channel map and the motor map;
    :mod:`.messages` state in NED/FRD, message schedules; :mod:`.vehicle` the state type and the
    physics interface; :mod:`.physics` the package's VehicleSimulator as that physics;
    :mod:`.px4` PX4's simulator interface; :mod:`.ardupilot` ArduPilot's JSON interface;
    :mod:`.gcs` ground-station link; :mod:`.bridge` the event loop tying them together.

Architecture: who owns the physics
    In lockstep the flight stack decides when time advances: the simulation may take exactly one step
    per actuator message and must answer with that step's sensors before the flight stack continues.
    Doing this across ROS topics (bridge publishes ``motor_speed_cmd``, simulator node steps, publishes
    ``imu``, bridge forwards) would put two DDS hops and two executors into every step, make the
    round trip depend on the simulator node's pacing (it runs on its own clock and rate), and leave
    no way to hold the simulator until the next actuator message. So the bridge has two modes:

    internal physics (``internal_physics: true``, the default with a flight stack)
        The bridge owns a simulation core in-process: the same
        :class:`~multirotor_ros.simulation.VehicleSimulator` vehicle as the simulator node (model,
        effects, faults, sensor noise), advanced by :class:`.physics.SimulatorPhysics` by exactly each
        frame's Δt in sub-steps no longer than the physics step. PX4 in lockstep: each
        HIL_ACTUATOR_CONTROLS advances to its stamp plus ``lockstep_step_s`` and is answered with that
        instant's HIL_SENSOR at once; PX4 without lockstep: steps on the wall clock with the latest
        command. ArduPilot: 1/frame_rate per new frame count. After each answer the node publishes what
        fell due (``odom``, ``imu``, ``motor_speeds``, optionally ``clock``) and the commands
        (``motor_speed_cmd``), so the identifier and every other node see the flight as if the simulator
        node flew it. Do not run a simulator node in the same namespace then: two sources would publish
        ``odom``. Without a connected flight stack the physics stands still: the vehicle keeps its state.

    external physics (``internal_physics: false``; the only mode without a flight stack)
        The simulator node owns the physics and runs on its own clock. The bridge subscribes ``odom``,
        ``imu`` and ``motor_speeds`` (as interfaces.md lists) and forwards: every ``imu`` message
        becomes a HIL_SENSOR (PX4) or answers a waiting frame (ArduPilot), and actuator messages become
        ``motor_speed_cmd``. Lockstep is not possible here: PX4 follows the simulator's time stamps,
        ArduPilot is answered at the simulator's pace, and the flight stack's IMU rate is the
        simulator's ``sensors.imu_rate_hz`` (100 Hz by default; PX4 wants 250 Hz). Use it to fly a
        flight stack against a simulator that other nodes also drive; prefer internal physics
        otherwise. Ground-station-only use (``flight_stack: none``) is this mode: telemetry from the
        topics, setpoints to ``setpoint``.

    The ground-station link works the same in both modes and runs on the wall clock. The per-step
    cost outside the physics is one pymavlink parse and up to three message packs (HIL_SENSOR every
    step, HIL_GPS and HIL_STATE_QUATERNION when due) written in one send (PX4), or one struct unpack and
    one formatted line (ArduPilot), all in the loop thread; ROS sees a step only through publishing,
    after the answer and at the graph's rates, never waits on it. bench/bench_mavlink.py (PX4-like peer)
    and bench/bench_ardupilot.py (the real ArduCopter) measure the answer time per frame beside the
    flight stack's own.
"""
