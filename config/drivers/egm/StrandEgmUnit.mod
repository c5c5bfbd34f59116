MODULE StrandEgmUnit
    ! strand-egm's RAPID side for a positioner (or track) that the controller runs as a mechanical
    ! unit of its own, in a motion task of its own (MultiMove): its own EGM channel, beside the
    ! robot's (StrandEgm.mod in the robot's task). strand-egm listens for it on
    ! [driver] external_axes_bind and answers it with the unit's share of the same command.
    ! Written for strand; the call sequence follows StrandEgm.mod. What is NOT confirmed from a
    ! public source is marked CHECK (docs/protocols/external-axes.md): ABB's EGM application
    ! manual, MultiMove section, is the reference.
    !
    ! Before running it:
    !  - Controller > Configuration > Communication > Transmission Protocol: add an instance named
    !    "STRAND_UNIT" of Type UDPUC, Remote Address = the strand PC's address on the robot
    !    network, Remote Port Number = [driver] external_axes_bind's port (e.g. 6511). Restart.
    !  - Load this module in the positioner's motion task; start it with the robot's task.
    !
    ! The unit sends its axes in feedBack.externalJoints (no robot joints) and follows
    ! planned.externalJoints: degrees for a rotary axis, mm for a linear one.

    LOCAL VAR egmident egm_id;
    LOCAL CONST egm_minmax band := [-0.1, 0.1];

    PROC main()
        EGMReset egm_id;
        EGMGetId egm_id;
        ! CHECK: the positioner's mechanical unit name (STN1 here) as configured in the controller.
        EGMSetupUC STN1, egm_id, "raw", "STRAND_UNIT", \Joint \CommTimeout:=1;
        ! CHECK: the switches that select a robot-less unit's axes; here the first two, as for a
        ! two-axis positioner (a one-axis table needs \J1 only).
        EGMActJoint egm_id \J1:=band \J2:=band \SampleRate:=4 \MaxSpeedDeviation:=100;
        EGMRunJoint egm_id, EGM_STOP_HOLD \J1 \J2 \CondTime:=1000000 \RampInTime:=0.05 \PosCorrGain:=1;
        EGMReset egm_id;
    ERROR
        IF ERRNO = ERR_UDPUC_COMM THEN
            ! strand-egm stopped answering for \CommTimeout: the unit holds; end the session.
            TPWrite "StrandEgmUnit: no answer from strand-egm; EGM stopped, unit held";
            EGMReset egm_id;
            RETURN;
        ENDIF
    ENDPROC
ENDMODULE
