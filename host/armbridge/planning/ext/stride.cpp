// OMPL's STRIDE (Gipson, Moll & Kavraki 2013) on a box state space whose validity, motion
// validity and goal distance are Python callables: the PyPI ompl wheel binds no STRIDE class,
// Debian's libompl-dev (OMPL 1.5.2) has it. Built on first use by armbridge.planning.ext.build.
//
// The planner runs in the calling thread with the GIL held, so every callback is a plain
// pybind11 call. States reach Python as 1-d float64 numpy arrays (copies).
#include <pybind11/functional.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <ompl/config.h>
#include <ompl/base/MotionValidator.h>
#include <ompl/base/PlannerData.h>
#include <ompl/base/PlannerTerminationCondition.h>
#include <ompl/base/ProjectionEvaluator.h>
#include <ompl/base/goals/GoalSampleableRegion.h>
#include <ompl/base/spaces/RealVectorStateSpace.h>
#include <ompl/geometric/PathGeometric.h>
#include <ompl/geometric/planners/stride/STRIDE.h>
#include <ompl/util/Console.h>
#include <ompl/util/RandomNumbers.h>

#include <chrono>
#include <memory>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

namespace py = pybind11;
namespace ob = ompl::base;
namespace og = ompl::geometric;

namespace {

using Vec = std::vector<double>;
long g_seed = -1;  // the seed in force (OMPL takes one per process)

py::array_t<double> to_array(const ob::State *s, unsigned int n) {
    const double *v = s->as<ob::RealVectorStateSpace::StateType>()->values;
    return py::array_t<double>(static_cast<py::ssize_t>(n), v);
}

void set_state(ob::State *s, const Vec &q) {
    double *v = s->as<ob::RealVectorStateSpace::StateType>()->values;
    for (std::size_t i = 0; i < q.size(); ++i) v[i] = q[i];
}

class PyValidity : public ob::StateValidityChecker {
  public:
    PyValidity(const ob::SpaceInformationPtr &si, py::function fn) : ob::StateValidityChecker(si), fn_(std::move(fn)) {}
    bool isValid(const ob::State *s) const override {
        return fn_(to_array(s, si_->getStateDimension())).cast<bool>();
    }

  private:
    py::function fn_;
};

// Every motion is asked of the Python checker whole; the lastValid overload keeps no partial
// motion (as the wheel's bindings do for RRTConnect and KPIECE1).
class PyMotion : public ob::MotionValidator {
  public:
    PyMotion(const ob::SpaceInformationPtr &si, py::function fn) : ob::MotionValidator(si), fn_(std::move(fn)) {}
    bool checkMotion(const ob::State *a, const ob::State *b) const override {
        unsigned int n = si_->getStateDimension();
        bool ok = fn_(to_array(a, n), to_array(b, n)).cast<bool>();
        ok ? ++valid_ : ++invalid_;
        return ok;
    }
    bool checkMotion(const ob::State *a, const ob::State *b, std::pair<ob::State *, double> &last) const override {
        bool ok = checkMotion(a, b);
        if (!ok) {
            if (last.first != nullptr) si_->copyState(last.first, a);
            last.second = 0.0;
        }
        return ok;
    }

  private:
    py::function fn_;
};

class PyGoal : public ob::GoalSampleableRegion {
  public:
    PyGoal(const ob::SpaceInformationPtr &si, py::function dist, std::vector<Vec> samples, double threshold,
           unsigned long seed)
        : ob::GoalSampleableRegion(si), dist_(std::move(dist)), samples_(std::move(samples)), rng_(seed) {
        setThreshold(threshold);
    }
    double distanceGoal(const ob::State *s) const override {
        return dist_(to_array(s, si_->getStateDimension())).cast<double>();
    }
    void sampleGoal(ob::State *s) const override {
        std::uniform_int_distribution<std::size_t> pick(0, samples_.size() - 1);
        set_state(s, samples_[pick(rng_)]);
    }
    unsigned int maxSampleCount() const override { return static_cast<unsigned int>(samples_.size()); }
    bool couldSample() const override { return !samples_.empty(); }

  private:
    py::function dist_;
    std::vector<Vec> samples_;
    mutable std::mt19937_64 rng_;
};

class PyProjection : public ob::ProjectionEvaluator {
  public:
    PyProjection(const ob::StateSpacePtr &space, py::function fn, unsigned int dim)
        : ob::ProjectionEvaluator(space), fn_(std::move(fn)), dim_(dim) {}
    unsigned int getDimension() const override { return dim_; }
    void project(const ob::State *s, Eigen::Ref<Eigen::VectorXd> out) const override {
        auto v = fn_(to_array(s, space_->getDimension())).cast<Vec>();
        if (v.size() != dim_) throw std::runtime_error("projection returned the wrong number of coordinates");
        for (unsigned int i = 0; i < dim_; ++i) out[i] = v[i];
    }
    void setup() override {
        inferCellSizes();
        ob::ProjectionEvaluator::setup();
    }

  private:
    py::function fn_;
    unsigned int dim_;
};

long seed_once(long seed) {
    if (g_seed < 0) {
        ompl::RNG::setSeed(static_cast<std::uint_fast32_t>(seed + 1));  // OMPL refuses seed 0
        g_seed = seed;
    }
    return g_seed;
}

py::dict solve(const Vec &lower, const Vec &upper, const Vec &start, const std::vector<Vec> &goal_states,
               py::function is_valid, py::function motion_valid, py::function goal_distance, double goal_threshold,
               double time_limit, long seed, double range, long iterations, py::object projection,
               unsigned int projection_dim) {
    const unsigned int n = static_cast<unsigned int>(lower.size());
    if (n == 0 || upper.size() != n || start.size() != n) throw std::invalid_argument("lower, upper, start sizes differ");
    for (const Vec &g : goal_states)
        if (g.size() != n) throw std::invalid_argument("a goal state has the wrong dimension");
    ompl::msg::setLogLevel(ompl::msg::LOG_WARN);
    long in_force = seed_once(seed);

    auto space = std::make_shared<ob::RealVectorStateSpace>(n);
    ob::RealVectorBounds bounds(n);
    for (unsigned int i = 0; i < n; ++i) {
        bounds.setLow(i, lower[i]);
        bounds.setHigh(i, upper[i]);
    }
    space->setBounds(bounds);
    auto si = std::make_shared<ob::SpaceInformation>(space);
    si->setStateValidityChecker(std::make_shared<PyValidity>(si, is_valid));
    si->setMotionValidator(std::make_shared<PyMotion>(si, motion_valid));
    si->setup();
    auto pdef = std::make_shared<ob::ProblemDefinition>(si);
    ob::ScopedState<> s0(space);
    set_state(s0.get(), start);
    pdef->addStartState(s0);
    pdef->setGoal(std::make_shared<PyGoal>(si, goal_distance, goal_states, goal_threshold,
                                           static_cast<unsigned long>(seed)));

    auto planner = std::make_shared<og::STRIDE>(si);
    if (range > 0) planner->setRange(range);
    if (!projection.is_none()) {
        planner->setProjectionEvaluator(
            std::make_shared<PyProjection>(space, projection.cast<py::function>(), projection_dim));
        planner->setUseProjectedDistance(true);
    }
    planner->setProblemDefinition(pdef);
    planner->setup();

    long count = 0;
    auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(time_limit);
    ob::PlannerTerminationCondition ptc([&]() {
        if (std::chrono::steady_clock::now() > deadline || (iterations > 0 && count >= iterations)) return true;
        ++count;
        return false;
    });
    auto t0 = std::chrono::steady_clock::now();
    ob::PlannerStatus status = planner->solve(ptc);
    double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();

    py::list path;
    bool solved = pdef->hasExactSolution();
    if (solved) {
        auto sol = pdef->getSolutionPath()->as<og::PathGeometric>();
        for (std::size_t i = 0; i < sol->getStateCount(); ++i) {
            const double *v = sol->getState(i)->as<ob::RealVectorStateSpace::StateType>()->values;
            path.append(Vec(v, v + n));
        }
    }
    ob::PlannerData pd(si);
    planner->getPlannerData(pd);
    py::dict out;
    out["solved"] = solved;
    out["path"] = path;
    out["vertices"] = pd.numVertices();
    out["status"] = status.asString();
    out["iterations"] = count;
    out["time_s"] = elapsed;
    out["range"] = planner->getRange();
    out["goal_bias"] = planner->getGoalBias();
    out["seed_in_force"] = in_force;
    return out;
}

}  // namespace

PYBIND11_MODULE(_stride, m) {
    m.doc() = "OMPL 1.5 STRIDE over Python validity / motion / goal callbacks (armbridge.planning.ext.stride)";
    m.def("solve", &solve, py::arg("lower"), py::arg("upper"), py::arg("start"), py::arg("goal_states"),
          py::arg("is_valid"), py::arg("motion_valid"), py::arg("goal_distance"), py::arg("goal_threshold"),
          py::arg("time_limit"), py::arg("seed"), py::arg("range") = 0.0, py::arg("iterations") = 0,
          py::arg("projection") = py::none(), py::arg("projection_dim") = 2);
    m.def("ompl_version", []() {
        return std::to_string(OMPL_MAJOR_VERSION) + "." + std::to_string(OMPL_MINOR_VERSION) + "." +
               std::to_string(OMPL_PATCH_VERSION);
    });
}
