MODULE StrandEgm
    ! strand-egm's RAPID side (joint mode): hand the robot to the sensor PC running strand-egm,
    ! and hold it where EGM leaves it when the session ends. Written for strand; the call sequence
    ! follows ABB's EGM application manual and the abb_libegm examples.
    !
    ! Before running it:
    !  - Controller > Configuration > Communication > Transmission Protocol: add an instance named
    !    "STRAND" of Type UDPUC, Remote Address = the strand PC's address on the robot network,
    !    Remote Port Number = [driver] bind's port (6510 by default). Restart the controller.
    !  - Move to a safe posture near the bed first (the first MoveAbsJ below), at 10 % override
    !    the first time. strand's service is started with `strand run --clock robot`, then
    !    strand-egm, then this program; the job is sent with strand-feed once strand-egm says
    !    "Holding -> Following".
    !
    ! The joint targets strand sends are absolute (degrees); the convergence band only matters for
    ! when EGMRunJoint returns, which with \CondTime:=1e6 is never while the sensor streams.
    !
    ! A cell with external axes (a positioner or a track in the robot file, after the six robot
    ! axes): strand-egm reads them from feedBack.externalJoints and sends their absolute targets in
    ! planned.externalJoints (degrees, or mm for a linear axis). They must belong to this task's
    ! mechanical units and follow EGM; how EGMActJoint/EGMRunJoint name them is not confirmed
    ! from a public source (docs/protocols/external-axes.md): check ABB's EGM manual first.

    LOCAL CONST jointtarget start := [[0, 0, 0, 0, 30, 0], [9E9, 9E9, 9E9, 9E9, 9E9, 9E9]];
    LOCAL VAR egmident egm_id;
    LOCAL CONST egm_minmax band := [-0.1, 0.1];

    PROC main()
        MoveAbsJ start, v100, fine, tool0;
        EGMReset egm_id;
        EGMGetId egm_id;
        ! 4 ms cycle (strand's [controller] rate_hz = 250), unfiltered ("raw") so that the
        ! robot follows strand's jerk-limited targets without another filter's delay.
        EGMSetupUC ROB_1, egm_id, "raw", "STRAND", \Joint \CommTimeout:=1;
        EGMActJoint egm_id \J1:=band \J2:=band \J3:=band \J4:=band \J5:=band \J6:=band
                    \SampleRate:=4 \MaxSpeedDeviation:=100;
        ! EGM_STOP_HOLD: when the session ends the robot stays where strand left it
        ! (EGM_STOP_RAMP_DOWN would drive it back to where EGM started).
        EGMRunJoint egm_id, EGM_STOP_HOLD \J1 \J2 \J3 \J4 \J5 \J6 \CondTime:=1000000 \RampInTime:=0.05 \PosCorrGain:=1;
        EGMReset egm_id;
    ERROR
        IF ERRNO = ERR_UDPUC_COMM THEN
            ! strand-egm stopped answering for \CommTimeout: the robot holds; end the session.
            TPWrite "StrandEgm: no answer from strand-egm; EGM stopped, robot held";
            EGMReset egm_id;
            RETURN;
        ENDIF
    ENDPROC
ENDMODULE
