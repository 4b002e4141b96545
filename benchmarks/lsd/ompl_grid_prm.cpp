// OMPL's PRM on an occupancy grid, all in C++ (the strongest configuration of OMPL a user can
// run on a grid): a compiled validity checker reads the grid, OMPL's DiscreteMotionValidator
// checks motions at half a cell. Driven by benchmarks/lsd_prm_campus.py, which compiles it
// against the system's libompl-dev (apt: libompl-dev) and interleaves it with jaxsem.
//
// stdin (text): H W resolution origin_x origin_y n k seed Q, then H*W chars '0'/'1' (row-major,
// row 0 at origin_y, 1 = obstacle), then Q lines "sx sy gx gy".
// stdout: one JSON object: build_s (growRoadmap to exactly n milestones), milestones, edges, and
// per query: query_s (start and goal linked to their k nearest milestones with checkMotion, then
// Dijkstra on the roadmap), found, length, path [[x, y], ...].
#include <ompl/base/SpaceInformation.h>
#include <ompl/base/spaces/RealVectorStateSpace.h>
#include <ompl/geometric/planners/prm/PRM.h>
#include <ompl/util/Console.h>
#include <ompl/util/RandomNumbers.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <iostream>
#include <limits>
#include <queue>
#include <string>
#include <vector>

namespace ob = ompl::base;
namespace og = ompl::geometric;
using Clock = std::chrono::steady_clock;

int main() {
  int H, W, n, k, Q;
  long seed;
  double res, ox, oy;
  std::cin >> H >> W >> res >> ox >> oy >> n >> k >> seed >> Q;
  std::string row;
  std::vector<unsigned char> occ(static_cast<size_t>(H) * W);
  size_t filled = 0;
  while (filled < occ.size() && std::cin >> row)
    for (char c : row) occ[filled++] = c == '1';
  std::vector<std::array<double, 4>> queries(Q);
  for (auto &q : queries) std::cin >> q[0] >> q[1] >> q[2] >> q[3];

  ompl::msg::setLogLevel(ompl::msg::LOG_ERROR);
  ompl::RNG::setSeed(seed + 1);
  auto space = std::make_shared<ob::RealVectorStateSpace>(2);
  ob::RealVectorBounds bounds(2);
  bounds.setLow(0, ox);
  bounds.setHigh(0, ox + W * res);
  bounds.setLow(1, oy);
  bounds.setHigh(1, oy + H * res);
  space->setBounds(bounds);
  auto si = std::make_shared<ob::SpaceInformation>(space);
  const unsigned char *grid = occ.data();
  si->setStateValidityChecker([=](const ob::State *s) {
    const double *v = s->as<ob::RealVectorStateSpace::StateType>()->values;
    double fx = std::floor((v[0] - ox) / res), fy = std::floor((v[1] - oy) / res);
    if (fx < 0 || fy < 0 || fx >= W || fy >= H) return false;
    return grid[static_cast<size_t>(fy) * W + static_cast<size_t>(fx)] == 0;
  });
  si->setStateValidityCheckingResolution(0.5 * res / space->getMaximumExtent());
  si->setup();
  auto pdef = std::make_shared<ob::ProblemDefinition>(si);
  auto planner = std::make_shared<og::PRM>(si);
  planner->setProblemDefinition(pdef);
  planner->setMaxNearestNeighbors(k);
  planner->setup();

  auto t0 = Clock::now();
  planner->growRoadmap(ob::PlannerTerminationCondition([&] { return planner->milestoneCount() >= (unsigned)n; }));
  double build_s = std::chrono::duration<double>(Clock::now() - t0).count();

  // The roadmap as an adjacency list (outside the clock: a harness artefact, not OMPL's cost).
  const og::PRM::Graph &G = planner->getRoadmap();
  auto state = boost::get(og::PRM::vertex_state_t(), G);
  auto index = boost::get(boost::vertex_index, G);
  const unsigned M = boost::num_vertices(G);
  std::vector<double> px(M), py(M);
  std::vector<std::vector<std::pair<unsigned, double>>> adj(M + 2);
  size_t edges = 0;
  for (auto [v, vend] = boost::vertices(G); v != vend; ++v) {
    const double *x = state[*v]->as<ob::RealVectorStateSpace::StateType>()->values;
    px[index[*v]] = x[0];
    py[index[*v]] = x[1];
  }
  for (auto [e, eend] = boost::edges(G); e != eend; ++e) {
    unsigned i = index[boost::source(*e, G)], j = index[boost::target(*e, G)];
    double w = std::hypot(px[i] - px[j], py[i] - py[j]);
    adj[i].push_back({j, w});
    adj[j].push_back({i, w});
    ++edges;
  }
  px.resize(M + 2);
  py.resize(M + 2);

  std::printf("{\"build_s\": %.9f, \"milestones\": %u, \"edges\": %zu, \"queries\": [", build_s, M, edges);
  ob::State *a = si->allocState(), *b = si->allocState();
  for (int qi = 0; qi < Q; ++qi) {
    auto tq = Clock::now();
    auto g = adj;  // the query's links do not change the roadmap
    for (int end = 0; end < 2; ++end) {
      unsigned q = M + end;
      px[q] = queries[qi][2 * end];
      py[q] = queries[qi][2 * end + 1];
      std::vector<std::pair<double, unsigned>> d(M);
      for (unsigned i = 0; i < M; ++i) d[i] = {std::hypot(px[i] - px[q], py[i] - py[q]), i};
      unsigned kk = std::min<unsigned>(k, M);
      std::partial_sort(d.begin(), d.begin() + kk, d.end());
      a->as<ob::RealVectorStateSpace::StateType>()->values[0] = px[q];
      a->as<ob::RealVectorStateSpace::StateType>()->values[1] = py[q];
      for (unsigned t = 0; t < kk; ++t) {
        unsigned j = d[t].second;
        b->as<ob::RealVectorStateSpace::StateType>()->values[0] = px[j];
        b->as<ob::RealVectorStateSpace::StateType>()->values[1] = py[j];
        if (si->checkMotion(a, b)) {
          g[q].push_back({j, d[t].first});
          g[j].push_back({q, d[t].first});
        }
      }
    }
    std::vector<double> dist(M + 2, std::numeric_limits<double>::infinity());
    std::vector<long> pred(M + 2, -1);
    std::priority_queue<std::pair<double, unsigned>, std::vector<std::pair<double, unsigned>>, std::greater<>> pq;
    dist[M] = 0;
    pq.push({0.0, M});
    while (!pq.empty()) {
      auto [du, u] = pq.top();
      pq.pop();
      if (du > dist[u]) continue;
      if (u == M + 1) break;
      for (auto [v, w] : g[u])
        if (du + w < dist[v]) {
          dist[v] = du + w;
          pred[v] = u;
          pq.push({dist[v], v});
        }
    }
    double query_s = std::chrono::duration<double>(Clock::now() - tq).count();
    bool found = std::isfinite(dist[M + 1]);
    std::printf("%s{\"query_s\": %.9f, \"found\": %s, \"length\": %.9f, \"path\": [", qi ? ", " : "", query_s,
                found ? "true" : "false", found ? dist[M + 1] : -1.0);
    if (found) {
      std::vector<unsigned> path;
      for (long v = M + 1; v >= 0; v = pred[v]) path.push_back(static_cast<unsigned>(v));
      std::reverse(path.begin(), path.end());
      for (size_t t = 0; t < path.size(); ++t) std::printf("%s[%.9f, %.9f]", t ? ", " : "", px[path[t]], py[path[t]]);
    }
    std::printf("]}");
  }
  std::printf("]}\n");
  si->freeState(a);
  si->freeState(b);
  return 0;
}
