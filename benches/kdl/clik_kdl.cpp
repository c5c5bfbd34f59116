// KDL's CLIK tick on the KUKA iiwa7, timed per tick: the baseline `strand-bench tick --kdl` sets the
// whole `Controller::step` against.
//
// The tick is KDL's canonical closed-loop step (the one ChainIkSolverPos_NR iterates): FK
// (ChainFkSolverPos_recursive), the pose error as a twist in the base frame (KDL::diff), the joint
// velocity from ChainIkSolverVel_pinv (its Jacobian and a Householder SVD pseudo-inverse) or from
// ChainIkSolverVel_wdls (damped least squares, lambda 1e-3: the Pinocchio bench's 1e-6 on J J^T),
// one full step (q += qdot). Both are timed, in turn; the JSON line's figures are the faster one's
// (the baseline is KDL at its best), "solver" says which, and stderr has both. The chain is read from the URDF here (KDL has no URDF reader outside ROS's
// kdl_parser), built as kdl_parser builds it; the TCP is 0.10 m along iiwa_link_ee's z.
// Targets: the Pinocchio bench's (benches/pinocchio/clik_dls.cpp): a 20 mm circle in the world x-y
// plane at 50 mm/s, 1 kHz, orientation held, from q0 = [0.2, 0.6, -0.1, -1.3, 0.2, 0.9, 0.3].
//
// Usage: clik_kdl URDF_PATH [TICKS]   (TICKS defaults to 200000)
// Prints one JSON line to stdout (the Pinocchio bench's keys, "kdl_version") and a human line to stderr.

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <type_traits>
#include <vector>

#include <kdl/chain.hpp>
#include <kdl/chainfksolverpos_recursive.hpp>
#include <kdl/chainiksolvervel_pinv.hpp>
#include <kdl/chainiksolvervel_wdls.hpp>
#include <kdl/frames.hpp>
#include <kdl/jntarray.hpp>

#ifndef KDL_VERSION_TEXT
#define KDL_VERSION_TEXT "1.5"
#endif

namespace
{
  const double RADIUS = 0.02; // m
  const double SPEED = 0.05;  // m/s
  const double DT = 1e-3;     // s
  const long WARMUP = 10000;

  inline int64_t now_ns()
  {
    timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return int64_t(ts.tv_sec) * 1000000000LL + ts.tv_nsec;
  }

  // The value of attribute `name` in the first tag `tag` inside `text`, or "".
  std::string attribute(const std::string & text, const std::string & tag, const std::string & name)
  {
    size_t at = text.find("<" + tag);
    if (at == std::string::npos)
      return "";
    size_t end = text.find('>', at);
    std::string element = text.substr(at, end - at);
    size_t a = element.find(" " + name + "=\"");
    if (a == std::string::npos)
      return "";
    a += name.size() + 3;
    return element.substr(a, element.find('"', a) - a);
  }

  KDL::Vector vector3(const std::string & text, double fallback)
  {
    if (text.empty())
      return KDL::Vector(fallback, fallback, fallback);
    std::istringstream in(text);
    double x, y, z;
    in >> x >> y >> z;
    return KDL::Vector(x, y, z);
  }

  struct UrdfJoint
  {
    std::string type, parent, child, origin_xyz, origin_rpy, axis;
  };

  // The chain from `root` to `tip`, built as ROS's kdl_parser builds it.
  bool chain_from_urdf(const std::string & path, const std::string & root, const std::string & tip, KDL::Chain & chain)
  {
    std::ifstream file(path);
    std::stringstream buffer;
    buffer << file.rdbuf();
    const std::string text = buffer.str();
    std::map<std::string, UrdfJoint> by_child;
    for (size_t at = text.find("<joint "); at != std::string::npos; at = text.find("<joint ", at + 1))
    {
      size_t end = text.find("</joint>", at);
      std::string body = text.substr(at, end - at);
      UrdfJoint j;
      j.type = attribute(body, "joint", "type");
      j.parent = attribute(body, "parent", "link");
      j.child = attribute(body, "child", "link");
      j.origin_xyz = attribute(body, "origin", "xyz");
      j.origin_rpy = attribute(body, "origin", "rpy");
      j.axis = attribute(body, "axis", "xyz");
      by_child[j.child] = j;
    }
    std::vector<UrdfJoint> path_joints;
    for (std::string link = tip; link != root;)
    {
      auto it = by_child.find(link);
      if (it == by_child.end())
        return false;
      path_joints.push_back(it->second);
      link = it->second.parent;
    }
    std::reverse(path_joints.begin(), path_joints.end());
    for (const UrdfJoint & j : path_joints)
    {
      const KDL::Vector rpy = vector3(j.origin_rpy, 0.);
      const KDL::Frame origin(KDL::Rotation::RPY(rpy.x(), rpy.y(), rpy.z()), vector3(j.origin_xyz, 0.));
      if (j.type == "revolute" || j.type == "continuous")
      {
        KDL::Vector axis = vector3(j.axis, 0.);
        axis.Normalize();
        chain.addSegment(KDL::Segment(j.child, KDL::Joint(j.child, origin.p, origin.M * axis, KDL::Joint::RotAxis), origin));
      }
      else if (j.type == "prismatic")
      {
        KDL::Vector axis = vector3(j.axis, 0.);
        axis.Normalize();
        chain.addSegment(KDL::Segment(j.child, KDL::Joint(j.child, origin.p, origin.M * axis, KDL::Joint::TransAxis), origin));
      }
      else
      {
        chain.addSegment(KDL::Segment(j.child, KDL::Joint(KDL::Joint::None), origin));
      }
    }
    return true;
  }

  int64_t percentile(const std::vector<int64_t> & sorted, double p)
  {
    size_t n = sorted.size();
    size_t idx = size_t(std::ceil(p * double(n)));
    idx = idx == 0 ? 0 : idx - 1;
    if (idx >= n)
      idx = n - 1;
    return sorted[idx];
  }

  // Everything one tick touches, allocated once; `Ik` is KDL's velocity solver.
  template<class Ik>
  struct Clik
  {
    KDL::ChainFkSolverPos_recursive fk;
    Ik ik;
    KDL::JntArray q, qdot;
    KDL::Frame tcp;

    Clik(const KDL::Chain & chain, const KDL::JntArray & q0)
    : fk(chain), ik(chain), q(q0), qdot(chain.getNrOfJoints())
    {
    }

    // One CLIK tick: FK, the error twist, the pseudo-inverse joint velocity, one full step.
    void tick(const KDL::Frame & target)
    {
      fk.JntToCart(q, tcp);
      const KDL::Twist error = KDL::diff(tcp, target);
      ik.CartToJnt(q, error, qdot);
      KDL::Add(q, qdot, q);
    }
  };

  struct Result
  {
    const char * solver;
    long long p50, p99, p999, p9999, max;
    double mean, max_error;
  };

  // Warm-up, then `ticks` ticks each timed alone; the tool after each against its target (untimed).
  template<class Ik, class Setup>
  Result run(const KDL::Chain & chain, const KDL::JntArray & q0, const std::vector<KDL::Frame> & targets, long ticks, Setup setup)
  {
    const size_t period = targets.size();
    std::vector<int64_t> dur(size_t(ticks), 0);
    Clik<Ik> clik(chain, q0);
    setup(clik.ik);
    size_t k = 0;
    for (long i = 0; i < WARMUP; ++i)
    {
      clik.tick(targets[k]);
      k = (k + 1) % period;
    }
    double max_pos_err = 0.;
    KDL::ChainFkSolverPos_recursive check(chain);
    for (long i = 0; i < ticks; ++i)
    {
      const KDL::Frame & target = targets[k];
      const int64_t t0 = now_ns();
      clik.tick(target);
      const int64_t t1 = now_ns();
      dur[size_t(i)] = t1 - t0;
      // The tool after the tick against its target (untimed).
      KDL::Frame after;
      check.JntToCart(clik.q, after);
      max_pos_err = std::max(max_pos_err, (after.p - target.p).Norm());
      k = (k + 1) % period;
    }
    double sum = 0.;
    for (int64_t d : dur)
      sum += double(d);
    std::sort(dur.begin(), dur.end());
    const char * name = std::is_same<Ik, KDL::ChainIkSolverVel_pinv>::value ? "pinv" : "wdls";
    return Result{name, (long long)percentile(dur, 0.50), (long long)percentile(dur, 0.99), (long long)percentile(dur, 0.999),
                  (long long)percentile(dur, 0.9999), (long long)dur.back(), sum / double(ticks), max_pos_err};
  }
} // namespace

int main(int argc, char ** argv)
{
  if (argc < 2 || argc > 3)
  {
    std::fprintf(stderr, "usage: %s URDF_PATH [TICKS]\n", argv[0]);
    return 2;
  }
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
  KDL::Chain chain;
  if (!chain_from_urdf(argv[1], "world", "iiwa_link_ee", chain) || chain.getNrOfJoints() != 7)
  {
    std::fprintf(stderr, "%s: expected the iiwa7 (7 joints from world to iiwa_link_ee)\n", argv[1]);
    return 1;
  }
  chain.addSegment(KDL::Segment("tcp", KDL::Joint(KDL::Joint::None), KDL::Frame(KDL::Vector(0., 0., 0.10))));

  KDL::JntArray q0(7);
  const double start_q[7] = {0.2, 0.6, -0.1, -1.3, 0.2, 0.9, 0.3};
  for (int i = 0; i < 7; ++i)
    q0(i) = start_q[i];

  KDL::Frame start;
  KDL::ChainFkSolverPos_recursive(chain).JntToCart(q0, start);
  const double omega = SPEED / RADIUS;
  const size_t period = size_t(2.0 * M_PI / omega * 1000.0);
  const KDL::Vector centre = start.p - RADIUS * KDL::Vector(1., 0., 0.);
  std::vector<KDL::Frame> targets;
  targets.reserve(period);
  for (size_t i = 0; i < period; ++i)
  {
    const double th = omega * double(i + 1) * DT;
    targets.emplace_back(start.M, centre + KDL::Vector(RADIUS * std::cos(th), RADIUS * std::sin(th), 0.));
  }

  const Result pinv = run<KDL::ChainIkSolverVel_pinv>(chain, q0, targets, ticks, [](KDL::ChainIkSolverVel_pinv &) {});
  const Result wdls = run<KDL::ChainIkSolverVel_wdls>(chain, q0, targets, ticks, [](KDL::ChainIkSolverVel_wdls & ik) { ik.setLambda(1e-3); });
  const Result & best = pinv.p50 <= wdls.p50 ? pinv : wdls;
  const long long p50 = best.p50, p99 = best.p99, p999 = best.p999, p9999 = best.p9999, max_ns = best.max;
  const double mean_ns = best.mean, max_pos_err = best.max_error;
  std::printf(
    "{\"name\":\"kdl_clik\",\"solver\":\"%s\",\"kdl_version\":\"%s\",\"ticks\":%ld,\"p50_ns\":%lld,\"p99_ns\":%lld,"
    "\"p999_ns\":%lld,\"p9999_ns\":%lld,\"max_ns\":%lld,\"mean_ns\":%.1f,\"max_position_error_m\":%.3e,"
    "\"pinv_p50_ns\":%lld,\"wdls_p50_ns\":%lld}\n",
    best.solver, KDL_VERSION_TEXT, ticks, p50, p99, p999, p9999, max_ns, mean_ns, max_pos_err, pinv.p50, wdls.p50);
  std::fflush(stdout);
  for (const Result * r : {&pinv, &wdls})
    std::fprintf(
      stderr, "KDL %s %s CLIK (iiwa7, TCP): %ld ticks, p50 %lld ns, p99 %lld ns, mean %.1f ns; tracking error max %.3e m\n",
      KDL_VERSION_TEXT, r->solver, ticks, r->p50, r->p99, r->mean, r->max_error);
  return 0;
}
