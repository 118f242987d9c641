#include <gtest/gtest.h>

#include <limits>

#include <string>
#include <vector>

#include "otfp/particles.hpp"

using namespace otfp;

TEST(ParticleSet, IdsStayStableAcrossRemovals) {
  ParticleSet ps(2);
  std::vector<ParticleId> ids;
  for (int i = 0; i < 10; ++i) ids.push_back(ps.add(Vec3(i, 2.0 * i, 5.0), 0.1 + i, 1.0 + i, 0.5 * i));
  EXPECT_EQ(ps.positions()[3][2], 0.0) << "coordinates beyond dim are zeroed";
  ps.remove(2);
  ps.remove_indices({0, 5});
  EXPECT_EQ(ps.size(), 7u);
  for (ParticleId id : {ids[0], ids[2], ids[5]}) EXPECT_EQ(ps.index_of(id), -1);
  for (int i : {1, 3, 4, 6, 7, 8, 9}) {
    const auto k = ps.index_of(ids[i]);
    ASSERT_GE(k, 0);
    EXPECT_EQ(ps.positions()[k][0], i);
    EXPECT_EQ(ps.widths()[k], 0.1 + i);
    EXPECT_EQ(ps.masses()[k], 1.0 + i);
    EXPECT_EQ(ps.birth_times()[k], 0.5 * i);
    EXPECT_EQ(ps.ids()[k], ids[i]);
  }
  const ParticleId fresh = ps.add(Vec3::Zero(), 1.0, 1.0);
  EXPECT_EQ(fresh, 10) << "ids are never reused";
}

TEST(ParticleSet, WidthIsInverseSqrtBeta) {
  ParticleSet ps(3);
  ps.add(Vec3::Zero(), 0.5, 1.0);
  EXPECT_DOUBLE_EQ(ps.beta(0), 4.0);
  ps.set_beta(0, 100.0);
  EXPECT_DOUBLE_EQ(ps.widths()[0], 0.1);
}

TEST(ParticleSet, RejectsBadInput) {
  ParticleSet ps(3);
  EXPECT_THROW(ps.add(Vec3::Zero(), -1.0, 1.0), InvalidArgument);
  EXPECT_THROW(ps.add(Vec3::Zero(), 1.0, 0.0), InvalidArgument);
  EXPECT_THROW(ps.add(Vec3(std::nan(""), 0, 0), 1.0, 1.0), InvalidArgument);
  EXPECT_THROW(ParticleSet(4), InvalidArgument);
  EXPECT_THROW(ps.remove_indices({0, 0}), InvalidArgument);
}

TEST(ParticleSet, AddWithIdKeepsTheIdAndAdvancesTheCounter) {
  ParticleSet ps(2);
  EXPECT_EQ(ps.add_with_id(7, Vec3(1.0, 2.0, 3.0), 0.25, 2.0, 0.5), 7);
  EXPECT_EQ(ps.next_id(), 8) << "next_id = max(next_id, id + 1)";
  EXPECT_EQ(ps.add_with_id(3, Vec3::Zero(), 1.0, 1.0), 3);
  EXPECT_EQ(ps.next_id(), 8) << "a smaller id leaves the counter";
  EXPECT_EQ(ps.add(Vec3::Zero(), 1.0, 1.0), 8) << "add() continues after the largest id";
  const auto k = ps.index_of(7);
  ASSERT_EQ(k, 0);
  EXPECT_EQ(ps.positions()[0], Vec3(1.0, 2.0, 0.0)) << "coordinates beyond dim are zeroed";
  EXPECT_EQ(ps.widths()[0], 0.25);
  EXPECT_EQ(ps.masses()[0], 2.0);
  EXPECT_EQ(ps.birth_times()[0], 0.5);
  EXPECT_EQ(ps.index_of(3), 1);
  EXPECT_EQ(ps.index_of(8), 2);
}

TEST(ParticleSet, AddWithIdRejectsNegativeAndDuplicateIds) {
  ParticleSet ps(3);
  ps.add_with_id(4, Vec3::Zero(), 1.0, 1.0);
  try {
    ps.add_with_id(4, Vec3::Zero(), 1.0, 1.0);
    ADD_FAILURE() << "duplicate id accepted";
  } catch (const InvalidArgument& e) {
    EXPECT_STREQ(e.what(), "particle id = '4': is already present");
  }
  try {
    ps.add_with_id(-1, Vec3::Zero(), 1.0, 1.0);
    ADD_FAILURE() << "negative id accepted";
  } catch (const InvalidArgument& e) {
    EXPECT_STREQ(e.what(), "particle id = '-1': must be >= 0");
  }
  EXPECT_THROW(ps.add_with_id(5, Vec3::Zero(), 0.0, 1.0), InvalidArgument);
  EXPECT_EQ(ps.size(), 1u) << "a rejected particle is not added";
  EXPECT_EQ(ps.next_id(), 5) << "a rejected particle leaves the counter";
  ps.remove(0);
  EXPECT_EQ(ps.add_with_id(4, Vec3::Zero(), 1.0, 1.0), 4) << "a removed id may be restored";
}

// Ids leave room for the counter: id + 1 (next_id) and every later add() must
// not overflow, so ids above kMaxParticleId (2^62) are refused with one line.
TEST(ParticleSet, IdsNearTwoToThe63AreRefused) {
  ParticleSet ps(3);
  for (const ParticleId id : {std::numeric_limits<ParticleId>::max(), std::numeric_limits<ParticleId>::max() - 1,
                              kMaxParticleId + 1}) {
    try {
      ps.add_with_id(id, Vec3::Zero(), 1.0, 1.0);
      ADD_FAILURE() << "id " << id << " accepted";
    } catch (const InvalidArgument& e) {
      EXPECT_EQ(std::string(e.what()), "particle id = '" + std::to_string(id) + "': must be <= 2^62 = " +
                                           std::to_string(kMaxParticleId));
    }
    EXPECT_THROW(ps.set_next_id(id + (id == std::numeric_limits<ParticleId>::max() ? 0 : 1)), InvalidArgument);
  }
  EXPECT_EQ(ps.size(), 0u);
  EXPECT_EQ(ps.add_with_id(kMaxParticleId, Vec3::Zero(), 1.0, 1.0), kMaxParticleId);
  EXPECT_EQ(ps.next_id(), kMaxParticleId + 1);
  EXPECT_EQ(ps.add(Vec3::Zero(), 1.0, 1.0), kMaxParticleId + 1) << "the counter goes on past the largest id";
}

TEST(ParticleSet, SetNextIdMustExceedEveryPresentId) {
  ParticleSet ps(1);
  ps.add_with_id(2, Vec3::Zero(), 1.0, 1.0);
  ps.add_with_id(9, Vec3::Zero(), 1.0, 1.0);
  ps.set_next_id(20);
  EXPECT_EQ(ps.add(Vec3::Zero(), 1.0, 1.0), 20);
  ps.set_next_id(21);
  EXPECT_EQ(ps.next_id(), 21);
  try {
    ps.set_next_id(20);
    ADD_FAILURE() << "next id equal to a present id accepted";
  } catch (const InvalidArgument& e) {
    EXPECT_STREQ(e.what(), "next particle id = '20': must be > every id present (id 20 is)");
  }
  EXPECT_THROW(ps.set_next_id(-1), InvalidArgument);
  EXPECT_EQ(ps.next_id(), 21) << "a rejected value leaves the counter";
  ParticleSet empty(3);
  empty.set_next_id(0);
  EXPECT_EQ(empty.add(Vec3::Zero(), 1.0, 1.0), 0);
}

TEST(Rng, IsReproducibleAndUniform) {
  Rng a(123), b(123), c(124);
  for (int i = 0; i < 100; ++i) EXPECT_EQ(a.next_u64(), b.next_u64());
  EXPECT_NE(a.next_u64(), c.next_u64());
  Rng r(5);
  const int n = 200000;
  int below_quarter = 0;
  double sum = 0.0, sum2 = 0.0;
  for (int i = 0; i < n; ++i) {
    if (r.uniform() < 0.25) ++below_quarter;
    const double z = r.normal();
    sum += z;
    sum2 += z * z;
  }
  const double sigma = std::sqrt(n * 0.25 * 0.75);
  EXPECT_NEAR(below_quarter, 0.25 * n, 3 * sigma);
  EXPECT_NEAR(sum / n, 0.0, 3.0 / std::sqrt(n));
  EXPECT_NEAR(sum2 / n, 1.0, 3.0 * std::sqrt(2.0 / n));
}

TEST(ParticleSet, AssignInPlaceKeepsTheArrays) {
  otfp::ParticleSet a(2), b(2);
  for (int i = 0; i < 5; ++i) a.add(otfp::Vec3(i, 0.0, 0.0), 0.1, 1.0);
  for (int i = 0; i < 5; ++i) b.add(otfp::Vec3(0.0, i, 0.0), 0.2 + i, 2.0, 0.5);
  b.reorder({4, 3, 2, 1, 0});
  const double* px = a.positions()[0].data();
  const double* ps = a.widths().data();
  a.assign_in_place(b);
  EXPECT_EQ(a.positions()[0].data(), px);  // same storage
  EXPECT_EQ(a.widths().data(), ps);
  for (std::size_t p = 0; p < 5; ++p) {
    EXPECT_EQ(a.positions()[p], b.positions()[p]);
    EXPECT_EQ(a.widths()[p], b.widths()[p]);
    EXPECT_EQ(a.ids()[p], b.ids()[p]);
    EXPECT_EQ(a.index_of(b.ids()[p]), static_cast<std::ptrdiff_t>(p));
  }
  EXPECT_EQ(a.next_id(), b.next_id());
  otfp::ParticleSet c(2);
  EXPECT_THROW(a.assign_in_place(c), otfp::InvalidArgument);
  otfp::ParticleSet d(3);
  for (int i = 0; i < 5; ++i) d.add(otfp::Vec3::Zero(), 0.1, 1.0);
  EXPECT_THROW(a.assign_in_place(d), otfp::InvalidArgument);
}

TEST(ParticleSet, SetBetaRejectsIndexOutOfRange) {
  ParticleSet ps(2);
  ps.add(Vec3::Zero(), 0.5, 1.0);
  ps.add(Vec3(1.0, 0.0, 0.0), 0.5, 1.0);
  EXPECT_THROW(ps.set_beta(2, 4.0), InvalidArgument);
  EXPECT_THROW(ps.set_beta(1000000, 4.0), InvalidArgument);
  EXPECT_EQ(ps.widths(), std::vector<double>({0.5, 0.5})) << "a refused call changes nothing";
  try {
    ps.set_beta(7, 4.0);
  } catch (const InvalidArgument& e) {
    EXPECT_NE(std::string(e.what()).find("7"), std::string::npos) << e.what();
  }
}

TEST(ParticleSet, ReorderRejectsOutOfRangeAndNonPermutations) {
  ParticleSet ps(2);
  for (int i = 0; i < 3; ++i) ps.add(Vec3(i, 0.0, 0.0), 0.1 + i, 1.0 + i);
  const std::vector<Vec3> x = ps.positions();
  const std::vector<ParticleId> ids = ps.ids();
  EXPECT_THROW(ps.reorder({0, 1, 3}), InvalidArgument);
  EXPECT_THROW(ps.reorder({0, 0, 0}), InvalidArgument);
  EXPECT_THROW(ps.reorder({2, 1, 2}), InvalidArgument);
  EXPECT_EQ(ps.positions(), x) << "a refused reorder changes nothing";
  EXPECT_EQ(ps.ids(), ids);
  for (ParticleId id : ids) EXPECT_EQ(ps.index_of(id), static_cast<std::ptrdiff_t>(id));
  ps.reorder({2, 0, 1});
  EXPECT_EQ(ps.ids(), std::vector<ParticleId>({2, 0, 1}));
  EXPECT_EQ(ps.index_of(2), 0);
}
