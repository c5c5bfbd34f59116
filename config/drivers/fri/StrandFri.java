// SPDX-License-Identifier: MIT OR Apache-2.0
//
// StrandFri: the Sunrise side of strand-fri (KUKA LBR iiwa, FRI joint-position overlay).
//
// A Sunrise.OS robot application that a cell installs on the iiwa's Sunrise cabinet. It opens an
// FRI session to the strand PC (where strand-fri is the FRI client, bound to UDP 30200). It waits
// until the link is good enough to command (MONITORING_READY), then holds the arm where it stands
// with a joint-position overlay, so that strand-fri's absolute joint positions drive the arm every
// FRI cycle. It does NOT move to a start pose: strand moves the arm itself, from wherever it
// stands. Position control only (no impedance mode, no tool attached here).
//
// Written for strand (same licence as the rest of the repository: MIT OR Apache-2.0). It contains
// no text from KUKA's FRI SDK or its examples. The API calls were learnt from these public sources:
//   - RobotLocomotion/drake-iiwa-driver: kuka-driver/sunrise_1.11|1.14/DrakeFRIPositionDriver.java
//     and its README (the KONI network, the 1.11 package rename);
//   - lbr-stack/fri: server_app/LBRServer.java, branch ros2-fri-1.15 (the session listener);
//   - kroshu/kuka_drivers: doc/wiki/4_Sunrise_FRI.md; lbr-stack/lbr_fri_ros2_stack:
//     lbr_fri_ros2_stack/doc/hardware_setup.rst (StationSetup.cat, installation);
//   - ahundt/grl: src/java/grl/src/grl/flatbuffer/FRI.java (paraphrases FRIConfiguration's javadoc);
//   - strand's own notes: docs/protocols/fri.md, sections 1, 4 and 7.
// Not compiled against KUKA's jars (only against stand-in classes with these signatures). Places where
// the API is not certain are marked [UNSURE].
//
// Package names: Sunrise.OS 1.11 and later spell it com.kuka.connectivity.fastRobotInterface.*
// (used below). Up to 1.10 the same classes are com.kuka.connectivity.fri.* (FRIConfiguration,
// FRISession, FRIJointOverlay; ClientCommandMode may be missing there [UNSURE]: then use
// `new FRIJointOverlay(session)`, which means POSITION). Sunrise/iiQKA 2.x uses com.kuka.fri.*
// (ClientCommandMode in com.kuka.fri.common, LBR in com.kuka.sensitivity), and later 2.x an
// interface API (com.kuka.fri.api.*: IFriSession, createFriSession(..)). Change only the imports
// for 1.x; the 2.x API needs a port of the session calls.
//
// Java level: Sunrise 1.x compiles applications as Java 6 [UNSURE about each 1.x release], so
// this file uses no lambdas, no diamond operator and no try-with-resources.

package strand;

import static com.kuka.roboticsAPI.motionModel.BasicMotions.positionHold;

import java.util.concurrent.TimeUnit;
import java.util.concurrent.TimeoutException;

import javax.inject.Inject;

import com.kuka.connectivity.fastRobotInterface.ClientCommandMode;
import com.kuka.connectivity.fastRobotInterface.FRIChannelInformation;
import com.kuka.connectivity.fastRobotInterface.FRIChannelInformation.FRIConnectionQuality;
import com.kuka.connectivity.fastRobotInterface.FRIConfiguration;
import com.kuka.connectivity.fastRobotInterface.FRIJointOverlay;
import com.kuka.connectivity.fastRobotInterface.FRISession;
import com.kuka.connectivity.fastRobotInterface.IFRISessionListener;
import com.kuka.roboticsAPI.applicationModel.RoboticsAPIApplication;
import com.kuka.roboticsAPI.deviceModel.LBR;
import com.kuka.roboticsAPI.executionModel.CommandInvalidException;
import com.kuka.roboticsAPI.motionModel.controlModeModel.PositionControlMode;

public class StrandFri extends RoboticsAPIApplication {

    // ---------------------------------------------------------------------------------------
    // Cell settings. Each can be overridden by a Sunrise process data entry of the id given
    // (src/RoboticsAPI.data.xml, or the Workbench's process data editor; editable on the
    // SmartPAD). Without the entry the constant is used. See README.md beside this file.
    // ---------------------------------------------------------------------------------------

    /** The strand PC's address on the KONI network (the FRI client). Process data "strandFriClientIp" (String). */
    private static final String CLIENT_IP = "192.170.10.200";

    /**
     * FRI send period in ms, 1..5. MUST equal strand's period: [controller] rate_hz = 1000 / this
     * (1 ms = 1000 Hz, 2 ms = 500 Hz, 4 ms = 250 Hz; strand refuses 5 ms = 200 Hz, below its
     * 250 Hz floor). Process data "strandFriSendPeriodMs" (Integer).
     */
    private static final int SEND_PERIOD_MS = 1;

    /** UDP port strand-fri binds on the PC (`--bind 0.0.0.0:30200`); KUKA recommends 30200..30209. Process data "strandFriPort" (Integer). */
    private static final int CLIENT_PORT = 30200;

    /**
     * After an overlay aborted by a connection-quality drop: false = end the application (an
     * operator looks at why first); true = wait for MONITORING_READY (quality GOOD again) and
     * start a new session and overlay, at most MAX_RESTARTS times. An abort with the quality still
     * GOOD (the controller refused a command or the motion) always ends the application.
     * Process data "strandFriRestartOnAbort" (Boolean).
     */
    private static final boolean RESTART_ON_ABORT = false;

    /** Restarts after an abort, in one run of the application (only with RESTART_ON_ABORT). */
    private static final int MAX_RESTARTS = 3;

    /** How long to wait for strand-fri to answer well enough (MONITORING_READY), in s. */
    private static final long AWAIT_READY_SECONDS = 30;

    // One answer per monitoring message: strand-fri answers every packet it receives.
    private static final int RECEIVE_MULTIPLIER = 1;

    // ---------------------------------------------------------------------------------------

    // The robot. [UNSURE on old releases] Field injection needs Sunrise 1.9 or so; otherwise set
    // it in initialize() with `lbr = getContext().getDeviceFromType(LBR.class);`.
    @Inject
    private LBR lbr;

    private String clientIp;
    private int sendPeriodMs;
    private int clientPort;
    private boolean restartOnAbort;

    // The open session (null when none); closed by run() and, if the app is stopped, by dispose().
    private FRISession session;

    // Set by the listener while an overlay runs: did the quality fall below GOOD?
    private volatile boolean overlayActive;
    private volatile boolean qualityDroppedDuringOverlay;

    /** Outcome of one session. */
    private enum Outcome { NOT_READY, ENDED, ABORTED_QUALITY, ABORTED_REFUSED }

    @Override
    public void initialize() {
        if (lbr == null) {
            lbr = getContext().getDeviceFromType(LBR.class);
        }
        clientIp = stringSetting("strandFriClientIp", CLIENT_IP);
        sendPeriodMs = intSetting("strandFriSendPeriodMs", SEND_PERIOD_MS);
        clientPort = intSetting("strandFriPort", CLIENT_PORT);
        restartOnAbort = booleanSetting("strandFriRestartOnAbort", RESTART_ON_ABORT);
        if (sendPeriodMs < 1 || sendPeriodMs > 5) {
            throw new IllegalArgumentException("StrandFri: send period " + sendPeriodMs
                    + " ms is outside 1..5 ms (strand runs at [controller] rate_hz = 1000 / period)");
        }
        if (clientPort < 1 || clientPort > 65535) {
            throw new IllegalArgumentException("StrandFri: port " + clientPort + " is not a UDP port");
        }
        getLogger().info("StrandFri: FRI client " + clientIp + ":" + clientPort + ", send period "
                + sendPeriodMs + " ms (strand must run at [controller] rate_hz = " + (1000.0 / sendPeriodMs)
                + "), restart on abort: "
                + (restartOnAbort ? ("yes, at most " + MAX_RESTARTS + " times") : "no"));
    }

    @Override
    public void run() {
        int restarts = 0;
        while (true) {
            Outcome outcome = runSession();
            if (outcome == Outcome.ABORTED_REFUSED) {
                getLogger().info("StrandFri: ending; a refused command is not restarted past. Find its cause, then start the application again.");
                return;
            }
            if (outcome != Outcome.ABORTED_QUALITY) {
                return;
            }
            if (!restartOnAbort) {
                getLogger().info("StrandFri: ending (restart on abort is off). Start the application again once the cause is fixed.");
                return;
            }
            if (restarts >= MAX_RESTARTS) {
                getLogger().error("StrandFri: overlay aborted " + (restarts + 1) + " times; ending. Find the cause before starting again.");
                return;
            }
            restarts++;
            getLogger().warn("StrandFri: restart " + restarts + " of " + MAX_RESTARTS
                    + ": opening a new session and waiting for quality GOOD (MONITORING_READY)");
        }
    }

    /**
     * One FRI session: open it, wait for MONITORING_READY, hold the pose under the joint overlay
     * until the overlay ends or aborts, close it. A new session per attempt is what
     * drake-iiwa-driver does after an abort; whether a second overlay on the same session would
     * also work is [UNSURE].
     */
    private Outcome runSession() {
        FRIConfiguration cfg = FRIConfiguration.createRemoteConfiguration(lbr, clientIp);
        cfg.setSendPeriodMilliSec(sendPeriodMs);
        cfg.setReceiveMultiplier(RECEIVE_MULTIPLIER);
        // The client's port; the controller uses the same port on its side unless
        // setPortOnController(..) is called (docs/protocols/fri.md, section 1).
        cfg.setPortOnRemote(clientPort);
        getLogger().info("StrandFri: opening FRI session to " + cfg.getHostName() + ":" + cfg.getPortOnRemote()
                + ", send period " + cfg.getSendPeriodMilliSec() + " ms, receive multiplier " + cfg.getReceiveMultiplier());

        FRISession s = new FRISession(cfg); // the controller starts sending monitoring messages here
        synchronized (this) {
            session = s;
        }
        try {
            s.addFRISessionListener(new IFRISessionListener() {
                @Override
                public void onFRISessionStateChanged(FRIChannelInformation info) {
                    getLogger().info("StrandFri: session state " + info.getFRISessionState() + " (quality "
                            + info.getQuality() + ", latency " + info.getLatency() + " ms, jitter " + info.getJitter() + " ms)");
                }

                @Override
                public void onFRIConnectionQualityChanged(FRIChannelInformation info) {
                    FRIConnectionQuality q = info.getQuality();
                    boolean tooLow = (q == FRIConnectionQuality.POOR || q == FRIConnectionQuality.FAIR);
                    if (tooLow && overlayActive) {
                        qualityDroppedDuringOverlay = true;
                    }
                    String line = "StrandFri: connection quality " + q + " (latency " + info.getLatency()
                            + " ms, jitter " + info.getJitter() + " ms)";
                    if (tooLow) {
                        getLogger().warn(line + ": below GOOD, commanding not possible");
                    } else {
                        getLogger().info(line);
                    }
                }
            });

            // Blocks until MONITORING_READY, i.e. strand-fri answers with quality GOOD or better.
            try {
                s.await(AWAIT_READY_SECONDS, TimeUnit.SECONDS);
            } catch (TimeoutException e) {
                FRIChannelInformation info = s.getFRIChannelInformation();
                getLogger().error("StrandFri: no FRI client answered well enough within " + AWAIT_READY_SECONDS
                        + " s (state " + info.getFRISessionState() + ", quality " + info.getQuality() + "). Start strand "
                        + "(`strand run --clock robot`) and strand-fri (`--bind 0.0.0.0:" + clientPort + "`) first; check the "
                        + "cable to KONI, the PC's address (" + clientIp + "), its firewall (UDP " + clientPort + ") and that "
                        + "strand's [controller] rate_hz = " + (1000.0 / sendPeriodMs) + ".");
                return Outcome.NOT_READY;
            }
            getLogger().info("StrandFri: MONITORING_READY; holding the pose under strand's joint positions (position control)");

            FRIJointOverlay overlay = new FRIJointOverlay(s, ClientCommandMode.POSITION);
            qualityDroppedDuringOverlay = false;
            overlayActive = true;
            try {
                // Hold forever (-1); the overlay replaces the held joint positions with strand's.
                lbr.move(positionHold(new PositionControlMode(), -1, TimeUnit.SECONDS).addMotionOverlay(overlay));
                getLogger().info("StrandFri: overlay motion ended");
                return Outcome.ENDED;
            } catch (CommandInvalidException e) {
                FRIChannelInformation info = s.getFRIChannelInformation();
                FRIConnectionQuality q = info.getQuality();
                boolean lowNow = (q == FRIConnectionQuality.POOR || q == FRIConnectionQuality.FAIR);
                boolean qualityCause = qualityDroppedDuringOverlay || lowNow;
                String why;
                if (qualityCause) {
                    why = "the connection quality fell below GOOD: strand-fri answered late or not at all "
                            + "(PC load or real-time set-up, the network, strand-fri stopped)";
                } else {
                    // [UNSURE] the controller's exact reasons: a commanded step beyond the joint
                    // velocity limits, a joint limit, a safety stop, the enabling switch in T1.
                    why = "the controller refused the motion or a commanded position (see the error on the SmartPAD: "
                            + "a jump beyond the joint velocity limit, a joint limit, a safety stop)";
                }
                getLogger().error("StrandFri: FRI overlay aborted: " + why + ". State " + info.getFRISessionState()
                        + ", quality " + q + ", latency " + info.getLatency() + " ms, jitter " + info.getJitter()
                        + " ms. Controller message: " + e.getLocalizedMessage());
                return qualityCause ? Outcome.ABORTED_QUALITY : Outcome.ABORTED_REFUSED;
            } finally {
                overlayActive = false;
            }
        } finally {
            closeSession();
        }
    }

    @Override
    public void dispose() {
        // The application was stopped (or run() threw): never leave a session open.
        closeSession();
        super.dispose();
    }

    private synchronized void closeSession() {
        if (session != null) {
            try {
                session.close(); // back to IDLE; strand-fri sees the monitoring stop
                getLogger().info("StrandFri: FRI session closed");
            } catch (RuntimeException e) {
                getLogger().warn("StrandFri: closing the FRI session: " + e.getLocalizedMessage());
            }
            session = null;
        }
    }

    // --- process data with fallbacks -------------------------------------------------------
    // [UNSURE] getProcessData(id) for an id the project does not define: it may return null or
    // throw; both fall back to the constant. getValue() is generic, so the value is read as an
    // Object and converted from its text (an entry typed String, Integer or Boolean all work).

    private Object processData(String id) {
        try {
            Object value = getApplicationData().getProcessData(id).getValue();
            return value;
        } catch (RuntimeException e) {
            return null;
        }
    }

    private String stringSetting(String id, String fallback) {
        Object v = processData(id);
        if (v == null || v.toString().trim().length() == 0) {
            return fallback;
        }
        getLogger().info("StrandFri: process data " + id + " = " + v);
        return v.toString().trim();
    }

    private int intSetting(String id, int fallback) {
        Object v = processData(id);
        if (v == null) {
            return fallback;
        }
        try {
            int parsed = (int) Math.round(Double.parseDouble(v.toString().trim()));
            getLogger().info("StrandFri: process data " + id + " = " + parsed);
            return parsed;
        } catch (NumberFormatException e) {
            getLogger().warn("StrandFri: process data " + id + " = " + v + " is not a number; using " + fallback);
            return fallback;
        }
    }

    private boolean booleanSetting(String id, boolean fallback) {
        Object v = processData(id);
        if (v == null) {
            return fallback;
        }
        String t = v.toString().trim();
        if (t.equalsIgnoreCase("true") || t.equals("1")) {
            return true;
        }
        if (t.equalsIgnoreCase("false") || t.equals("0")) {
            return false;
        }
        getLogger().warn("StrandFri: process data " + id + " = " + v + " is not true/false; using " + fallback);
        return fallback;
    }
}
