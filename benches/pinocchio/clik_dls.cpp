// Pinocchio's damped-least-squares CLIK tick on the KUKA iiwa7, timed per tick.
//
// The tick is Pinocchio's own DLS inverse-kinematics step (examples/inverse-kinematics.cpp, and the
// "Inverse kinematics (clik)" doc page) with a frame (the TCP, 0.10 m along iiwa_link_ee's z) instead
// of a joint, and one full Newton step per tick (q = integrate(q, v)) instead of v * DT.
// Targets: 20 mm circle in the world x-y plane at 50 mm/s, 1 kHz, orientation held; the same table as
// benches/kin.rs (floor(2*pi/omega*1000) entries, entry i at angle omega*(i+1)*dt, then wrap).
//
// Usage: clik_dls URDF_PATH [TICKS]   (TICKS defaults to 200000)
// Prints one JSON line to stdout and a human line to stderr.

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <string>
#include <vector>

#include "pinocchio/config.hpp"
#include "pinocchio/spatial.hpp"
#include "pinocchio/multibody.hpp"
#include "pinocchio/parsers/urdf.hpp"
#include "pinocchio/algorithm/kinematics.hpp"
#include "pinocchio/algorithm/jacobian.hpp"
#include "pinocchio/algorithm/frames.hpp"
#include "pinocchio/algorithm/joint-configuration.hpp"

// Heap allocations are counted (not prevented) by interposing malloc: Eigen's dynamic-size
// temporaries go through std::malloc. One increment per call; reported on stderr only.
extern "C" void * __libc_malloc(size_t);
static volatile uint64_t g_mallocs = 0;
extern "C" void * malloc(size_t n)
{
  g_mallocs = g_mallocs + 1;
  return __libc_malloc(n);
}

namespace
{
  typedef Eigen::Matrix<double, 6, 1> Vector6d;
  typedef Eigen::Matrix<double, 6, 6> Matrix6d;

  const double DT = 1e-3;     // s, 1 kHz
  const double DAMP = 1e-6;   // DLS damping, as in Pinocchio's example
  const double RADIUS = 0.02; // m
  const double SPEED = 0.05;  // m/s
  const long WARMUP = 10000;

  inline int64_t now_ns()
  {
    timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return int64_t(ts.tv_sec) * 1000000000LL + ts.tv_nsec;
  }

  // Everything one tick touches, allocated once.
  struct Clik
  {
    const pinocchio::Model & model;
    pinocchio::Data data;
    pinocchio::FrameIndex tcp;
    pinocchio::Data::Matrix6x J;
    Eigen::VectorXd q;
    Eigen::VectorXd v;
    Vector6d err;

    Clik(const pinocchio::Model & m, pinocchio::FrameIndex tcp_id, const Eigen::VectorXd & q0)
    : model(m)
    , data(m)
    , tcp(tcp_id)
    , J(6, m.nv)
    , q(q0)
    , v(m.nv)
    {
      J.setZero();
      v.setZero();
      err.setZero();
    }

    // One CLIK tick: Pinocchio's canonical DLS step, frame instead of joint, full step.
    void tick(const pinocchio::SE3 & oMdes)
    {
      pinocchio::forwardKinematics(model, data, q);
      pinocchio::updateFramePlacement(model, data, tcp);
      const pinocchio::SE3 iMd = data.oMf[tcp].actInv(oMdes);
      err = pinocchio::log6(iMd).toVector(); // in the TCP frame
      pinocchio::computeFrameJacobian(model, data, q, tcp, pinocchio::LOCAL, J); // 6x7
      pinocchio::Data::Matrix6 Jlog;
      pinocchio::Jlog6(iMd.inverse(), Jlog);
      J = -Jlog * J;
      Matrix6d JJt;
      JJt.noalias() = J * J.transpose();
      JJt.diagonal().array() += DAMP;
      v.noalias() = -J.transpose() * JJt.ldlt().solve(err);
      q = pinocchio::integrate(model, q, v); // one full DLS Newton step per tick
    }
  };

  int64_t percentile(const std::vector<int64_t> & sorted, double p)
  {
    // nearest rank
    size_t n = sorted.size();
    size_t idx = size_t(std::ceil(p * double(n)));
    idx = idx == 0 ? 0 : idx - 1;
    if (idx >= n)
      idx = n - 1;
    return sorted[idx];
  }
} // namespace

int main(int argc, char ** argv)
{
  if (argc < 2 || argc > 3)
  {
    std::fprintf(stderr, "usage: %s URDF_PATH [TICKS]\n", argv[0]);
    return 2;
  }
  const std::string urdf = argv[1];
  long ticks = 200000;
  if (argc == 3)
  {
    char * end = nullptr;
    errno = 0;
    ticks = std::strtol(argv[2], &end, 10);
    if (errno != 0 || end == argv[2] || *end != '\0' || ticks <= 0)
    {
      std::fprintf(stderr, "TICKS must be a positive integer, got '%s'\n", argv[2]);
      return 2;
    }
  }

  pinocchio::Model model;
  try
  {
    pinocchio::urdf::buildModel(urdf, model);
  }
  catch (const std::exception & e)
  {
    std::fprintf(stderr, "cannot load %s: %s\n", urdf.c_str(), e.what());
    return 1;
  }
  if (model.nq != 7 || model.nv != 7 || !model.existFrame("iiwa_link_ee"))
  {
    std::fprintf(
      stderr, "%s: expected the iiwa7 (7 dof, iiwa_link_ee), got nq=%d\n", urdf.c_str(), model.nq);
    return 1;
  }

  // TCP: 0.10 m along iiwa_link_ee's z, as an operational frame.
  const pinocchio::FrameIndex ee = model.getFrameId("iiwa_link_ee");
  const pinocchio::Frame & ee_frame = model.frames[ee];
  const pinocchio::SE3 ee_M_tcp(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0., 0., 0.10));
  const pinocchio::FrameIndex tcp = model.addFrame(pinocchio::Frame(
    "tcp", ee_frame.parentJoint, ee, ee_frame.placement * ee_M_tcp, pinocchio::OP_FRAME));

  Eigen::VectorXd q0(7);
  q0 << 0.2, 0.6, -0.1, -1.3, 0.2, 0.9, 0.3;

  // Target table (untimed): one period of the circle, entry i at angle omega*(i+1)*dt.
  pinocchio::SE3 start;
  {
    pinocchio::Data d(model);
    pinocchio::forwardKinematics(model, d, q0);
    start = pinocchio::updateFramePlacement(model, d, tcp);
  }
  const double omega = SPEED / RADIUS;
  const size_t period = size_t(2.0 * M_PI / omega * 1000.0); // 2513 ticks
  const Eigen::Vector3d centre = start.translation() - RADIUS * Eigen::Vector3d::UnitX();
  std::vector<pinocchio::SE3> targets;
  targets.reserve(period);
  for (size_t i = 0; i < period; ++i)
  {
    const double th = omega * double(i + 1) * DT;
    targets.emplace_back(
      start.rotation(), centre + Eigen::Vector3d(RADIUS * std::cos(th), RADIUS * std::sin(th), 0.));
  }

  std::vector<int64_t> dur(size_t(ticks), 0); // preallocated, touched before timing

  // --- CLIK: warm-up, then per-tick timing ---
  Clik clik(model, tcp, q0);
  size_t k = 0;
  for (long i = 0; i < WARMUP; ++i)
  {
    clik.tick(targets[k]);
    k = (k + 1) % period;
  }
  const uint64_t mallocs_before = g_mallocs;
  for (long i = 0; i < ticks; ++i)
  {
    const pinocchio::SE3 & target = targets[k];
    const int64_t t0 = now_ns();
    clik.tick(target);
    const int64_t t1 = now_ns();
    dur[size_t(i)] = t1 - t0;
    k = (k + 1) % period;
  }
  const double mallocs_per_tick = double(g_mallocs - mallocs_before) / double(ticks);
  const Eigen::VectorXd q_end = clik.q;

  double sum = 0.;
  for (int64_t d : dur)
    sum += double(d);
  const double mean_ns = sum / double(ticks);
  std::sort(dur.begin(), dur.end());
  const int64_t p50 = percentile(dur, 0.50), p90 = percentile(dur, 0.90),
                p99 = percentile(dur, 0.99), p999 = percentile(dur, 0.999),
                p9999 = percentile(dur, 0.9999), min_ns = dur.front(), max_ns = dur.back();

  // --- FK + Jacobian alone (forwardKinematics + computeFrameJacobian), same q sequence ---
  {
    Clik fk(model, tcp, q0);
    for (long i = 0; i < WARMUP; ++i)
    {
      pinocchio::forwardKinematics(model, fk.data, fk.q);
      pinocchio::computeFrameJacobian(model, fk.data, fk.q, tcp, pinocchio::LOCAL, fk.J);
    }
    Clik walker(model, tcp, q0); // replays the CLIK trajectory (untimed) to vary q
    k = 0;
    for (long i = 0; i < ticks; ++i)
    {
      const int64_t t0 = now_ns();
      pinocchio::forwardKinematics(model, fk.data, walker.q);
      pinocchio::computeFrameJacobian(model, fk.data, walker.q, tcp, pinocchio::LOCAL, fk.J);
      const int64_t t1 = now_ns();
      dur[size_t(i)] = t1 - t0;
      walker.tick(targets[k]);
      k = (k + 1) % period;
    }
  }
  std::sort(dur.begin(), dur.end());
  const int64_t fkj_p50 = percentile(dur, 0.50);

  // --- Tracking error (untimed replay of the same warm-up + timed trajectory from q0) ---
  // After tick for target k, the TCP of the new q against target k.
  double max_pos_err = 0., max_rot_err = 0., last_pos_err = 0.;
  {
    Clik replay(model, tcp, q0);
    pinocchio::Data check(model);
    k = 0;
    for (long i = 0; i < WARMUP + ticks; ++i)
    {
      replay.tick(targets[k]);
      pinocchio::forwardKinematics(model, check, replay.q);
      const pinocchio::SE3 & oMf = pinocchio::updateFramePlacement(model, check, tcp);
      last_pos_err = (oMf.translation() - targets[k].translation()).norm();
      const double rot_err =
        pinocchio::log3(Eigen::Matrix3d(oMf.rotation().transpose() * targets[k].rotation())).norm();
      max_pos_err = std::max(max_pos_err, last_pos_err);
      max_rot_err = std::max(max_rot_err, rot_err);
      k = (k + 1) % period;
    }
    if ((replay.q - q_end).norm() != 0.)
      std::fprintf(stderr, "warning: replay diverged from the timed run\n");
  }

  // Timer overhead (back-to-back clock reads), for context.
  int64_t overhead = INT64_MAX;
  for (int i = 0; i < 10000; ++i)
  {
    const int64_t a = now_ns();
    const int64_t b = now_ns();
    overhead = std::min(overhead, b - a);
  }

  std::printf(
    "{\"name\":\"pinocchio_dls_clik\",\"pinocchio_version\":\"%s\",\"ticks\":%ld,"
    "\"p50_ns\":%lld,\"p90_ns\":%lld,\"p99_ns\":%lld,\"p999_ns\":%lld,\"p9999_ns\":%lld,"
    "\"max_ns\":%lld,\"mean_ns\":%.1f,\"min_ns\":%lld,"
    "\"max_position_error_m\":%.3e,\"fk_jacobian_p50_ns\":%lld}\n",
    PINOCCHIO_VERSION, ticks, (long long)p50, (long long)p90, (long long)p99, (long long)p999,
    (long long)p9999, (long long)max_ns, mean_ns, (long long)min_ns, max_pos_err,
    (long long)fkj_p50);
  std::fflush(stdout);
  std::fprintf(
    stderr,
    "pinocchio %s DLS CLIK (iiwa7, TCP frame): %ld ticks, p50 %lld ns, p90 %lld ns, p99 %lld ns, "
    "mean %.1f ns, min %lld ns, max %lld ns; FK+Jacobian p50 %lld ns; tracking error max %.3e m "
    "(last %.3e m), orientation max %.3e rad; %.2f mallocs/tick; timer overhead %lld ns\n",
    PINOCCHIO_VERSION, ticks, (long long)p50, (long long)p90, (long long)p99, mean_ns,
    (long long)min_ns, (long long)max_ns, (long long)fkj_p50, max_pos_err, last_pos_err, max_rot_err,
    mallocs_per_tick, (long long)overhead);
  return 0;
}
