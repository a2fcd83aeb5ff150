#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include "arref/robot/joint_motion.h"
#include "arref/robot/robot_model.h"
#include "test_support.h"

namespace arref {
namespace {

using testing::Kr5PackageDir;

RobotModel LoadOrDie(const std::string& urdf, const RobotLoadOptions& options = {}) {
  auto robot = RobotModel::Load(urdf, options);
  EXPECT_TRUE(robot.ok()) << robot.status().ToString();
  return std::move(robot).value();
}

Iso3 Tool0(const RobotModel& robot, const JointValues& joints = {}) {
  auto poses = robot.LinkPoses(joints);
  EXPECT_TRUE(poses.ok()) << poses.status().ToString();
  return poses->at("tool0");
}

TEST(BuiltinRobot, HasKr5Kinematics) {
  const RobotModel robot = LoadOrDie(testing::BuiltinRobotUrdf());
  EXPECT_EQ(robot.ActuatedJoints().size(), 6u);
  EXPECT_TRUE(Tool0(robot).translation().isApprox(Vec3(1.515, 0, 0.52), 1e-9));
  auto mesh = robot.PosedMesh({});
  ASSERT_TRUE(mesh.ok());
  EXPECT_GT(mesh->SurfaceArea(), 1.0);
  EXPECT_LT(mesh->SurfaceArea(), 6.0);
}

TEST(BuiltinRobot, JointA1RotatesTheArmAboutVerticalAxis) {
  const RobotModel robot = LoadOrDie(testing::BuiltinRobotUrdf());
  // joint_a1's frame is flipped (rpy pi 0 0), so a positive angle turns the arm clockwise seen from above.
  const Vec3 p = Tool0(robot, {{"joint_a1", M_PI / 2}}).translation();
  EXPECT_NEAR(p.z(), 0.52, 1e-9);
  EXPECT_NEAR(std::hypot(p.x(), p.y()), 1.515, 1e-9);
  EXPECT_NEAR(std::abs(p.y()), 1.515, 1e-9);
}

TEST(RobotModel, RejectsUnknownJointAndOutOfLimitValues) {
  const RobotModel robot = LoadOrDie(testing::BuiltinRobotUrdf());
  auto unknown = robot.LinkPoses({{"joint_a9", 0.1}});
  ASSERT_FALSE(unknown.ok());
  EXPECT_EQ(unknown.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(unknown.status().message().find("joint_a9"), std::string::npos);
  EXPECT_NE(unknown.status().message().find("joint_a1"), std::string::npos) << "lists the known joints";
  auto outside = robot.LinkPoses({{"joint_a2", 2.0}});  // upper limit 1.134
  ASSERT_FALSE(outside.ok());
  EXPECT_NE(outside.status().message().find("limits"), std::string::npos);
  EXPECT_FALSE(robot.LinkPoses({{"joint_a2", std::nan("")}}).ok());
}

// A small URDF exercising prismatic, continuous, mimic joints, primitives and mesh scale.
std::string WriteTestUrdf(const std::string& dir) {
  std::filesystem::create_directories(dir + "/meshes");
  const std::string urdf = R"(<?xml version="1.0"?>
<robot name="test_bot">
  <link name="base"><visual><geometry><box size="1 1 1"/></geometry></visual></link>
  <link name="slider"><visual><origin xyz="0 0 1" rpy="0 0 0"/><geometry><sphere radius="0.5"/></geometry></visual></link>
  <link name="wheel"><visual><geometry><cylinder radius="0.1" length="0.2"/></geometry></visual></link>
  <link name="twin"/>
  <link name="scaled"><visual><geometry><mesh filename="meshes/box.stl" scale="2 2 2"/></geometry></visual></link>
  <joint name="slide" type="prismatic"><parent link="base"/><child link="slider"/><axis xyz="1 0 0"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
  <joint name="spin" type="continuous"><parent link="slider"/><child link="wheel"/><origin xyz="0 0 2"/><axis xyz="0 0 1"/></joint>
  <joint name="follow" type="prismatic"><parent link="base"/><child link="twin"/><axis xyz="0 1 0"/>
    <limit lower="-5" upper="5" effort="1" velocity="1"/><mimic joint="slide" multiplier="2" offset="0.5"/></joint>
  <joint name="fix" type="fixed"><parent link="base"/><child link="scaled"/></joint>
</robot>)";
  std::ofstream(dir + "/test.urdf") << urdf;
  // A unit cube as ASCII STL.
  auto cube = RobotModel::FromString(
      R"(<robot name="c"><link name="l"><visual><geometry><box size="1 1 1"/></geometry></visual></link></robot>)", dir);
  EXPECT_TRUE(cube.ok());
  EXPECT_TRUE(SaveMeshFile(*cube->LinkMesh("l"), dir + "/meshes/box.stl").ok());
  return dir + "/test.urdf";
}

TEST(RobotModel, PrismaticContinuousMimicAndScale) {
  const testing::ScopedTempDir tmp;
  const std::string dir = tmp.path();
  const RobotModel robot = LoadOrDie(WriteTestUrdf(dir));
  const auto actuated = robot.ActuatedJoints();
  ASSERT_EQ(actuated.size(), 2u) << "the mimic joint is not actuated";
  auto poses = robot.LinkPoses({{"slide", 0.25}, {"spin", 10.0}});
  ASSERT_TRUE(poses.ok()) << poses.status().ToString();
  EXPECT_TRUE(poses->at("slider").translation().isApprox(Vec3(0.25, 0, 0)));
  EXPECT_TRUE(poses->at("wheel").translation().isApprox(Vec3(0.25, 0, 2)));
  EXPECT_TRUE(poses->at("wheel").rotation().isApprox(Eigen::AngleAxisd(10.0, Vec3::UnitZ()).toRotationMatrix(), 1e-9))
      << "continuous joints take any angle";
  EXPECT_TRUE(poses->at("twin").translation().isApprox(Vec3(0, 1.0, 0))) << "mimic: 2 * 0.25 + 0.5";
  auto mimic_set = robot.LinkPoses({{"follow", 0.1}});
  EXPECT_FALSE(mimic_set.ok());
  const TriangleMesh* scaled = robot.LinkMesh("scaled");
  ASSERT_NE(scaled, nullptr);
  const Aabb box = BoundsOf(scaled->vertices);
  EXPECT_TRUE(box.max.isApprox(Vec3f(1, 1, 1))) << "<mesh scale=2> doubles the unit cube";
  EXPECT_NEAR(scaled->SurfaceArea(), 24.0, 1e-4);
  EXPECT_NEAR(robot.LinkMesh("base")->SurfaceArea(), 6.0, 1e-5);
  EXPECT_NEAR(robot.LinkMesh("slider")->SurfaceArea(), M_PI, 0.05);
}

TEST(RobotModel, MissingMeshNamesUriAndPlacesLooked) {
  const std::string xml = R"(<robot name="r"><link name="l"><visual><geometry>
      <mesh filename="package://no_such_pkg/meshes/x.stl"/></geometry></visual></link></robot>)";
  auto robot = RobotModel::FromString(xml, "/tmp", RobotLoadOptions{.package_path = {"/opt/a", "/opt/b"}});
  ASSERT_FALSE(robot.ok());
  EXPECT_EQ(robot.status().code(), StatusCode::kNotFound);
  const std::string& m = robot.status().message();
  EXPECT_NE(m.find("package://no_such_pkg/meshes/x.stl"), std::string::npos) << m;
  EXPECT_NE(m.find("/opt/a/no_such_pkg/meshes/x.stl"), std::string::npos) << m;
  EXPECT_NE(m.find("/opt/b"), std::string::npos) << m;
  EXPECT_NE(m.find("link 'l'"), std::string::npos) << m;
}

TEST(RobotModel, BadUrdfIsAClearError) {
  auto robot = RobotModel::FromString("<robot name='x'><link name=", "/tmp");
  ASSERT_FALSE(robot.ok());
  EXPECT_EQ(robot.status().code(), StatusCode::kIoError);
  auto missing = RobotModel::Load("/nonexistent/robot.urdf");
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.status().message().find("/nonexistent/robot.urdf"), std::string::npos);
}

// Joints must form a tree: urdfdom accepted a loop beside the tree (links without a pose) and
// kept loops and links with two parents alive in memory (found by tests/fuzz/urdf_fuzz.cpp as
// leaks). Both are errors naming the link.
TEST(RobotModel, JointLoopsAndTwoParentsAreRejected) {
  const std::string xml = R"(<robot name="loop">
    <link name="base"/><link name="a"/><link name="b"/><link name="c"/>
    <joint name="j0" type="fixed"><parent link="base"/><child link="c"/></joint>
    <joint name="j1" type="fixed"><parent link="b"/><child link="a"/></joint>
    <joint name="j2" type="fixed"><parent link="a"/><child link="b"/></joint>
  </robot>)";
  auto loop = RobotModel::FromString(xml, "/tmp");
  ASSERT_FALSE(loop.ok());
  EXPECT_EQ(loop.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(loop.status().message().find("the joints above link 'a' form a loop"), std::string::npos)
      << loop.status().message();

  std::string two_parents = xml;
  two_parents.replace(two_parents.find(R"(<child link="b"/>)"), 17, R"(<child link="c"/>)");
  auto twice = RobotModel::FromString(two_parents, "/tmp");
  ASSERT_FALSE(twice.ok());
  EXPECT_NE(twice.status().message().find("link 'c' is the child of two joints"), std::string::npos)
      << twice.status().message();

  std::string tree = xml;  // the same links as a chain base - c - a - b
  tree.replace(tree.find(R"(<parent link="b"/>)"), 18, R"(<parent link="c"/>)");
  auto chain = RobotModel::FromString(tree, "/tmp");
  ASSERT_TRUE(chain.ok()) << chain.status().message();
  EXPECT_EQ(chain->root_link(), "base");
}

// TinyXML reads a UTF-8 character's whole sequence without looking for the end of the text, so
// a file cut inside one made it read past the buffer (found by tests/fuzz/urdf_fuzz.cpp under
// ASan); a NUL ended the document early, unseen. Both are refused naming the byte, while UTF-8
// text (a German comment, a name with an accent) still loads.
TEST(RobotModel, TextThatIsNotUtf8IsRefusedNamingTheByte) {
  const std::string xml = "<robot name='r\xC3\xA9'><!-- Gelenk \xC3\xA4 \xE2\x82\xAC \xF0\x9F\xA4\x96 --><link name='a'/></robot>";
  auto good = RobotModel::FromString(xml, "/tmp");
  ASSERT_TRUE(good.ok()) << good.status().message();
  EXPECT_EQ(good->name(), "r\xC3\xA9");

  for (const std::string& cut : {std::string("\xF0"), std::string("\xE2\x82"), std::string("\xC3")}) {
    auto bad = RobotModel::FromString(xml + cut, "/tmp");
    ASSERT_FALSE(bad.ok());
    EXPECT_EQ(bad.status().code(), StatusCode::kInvalidArgument);
    EXPECT_NE(bad.status().message().find("byte " + std::to_string(xml.size()) + " "), std::string::npos)
        << bad.status().message();
    EXPECT_NE(bad.status().message().find("UTF-8"), std::string::npos) << bad.status().message();
  }
  const std::size_t umlaut = xml.find("\xC3\xA4");
  const std::string latin1 = xml.substr(0, umlaut) + '\xE4' + xml.substr(umlaut + 2);  // "ä" as Latin-1: E4, a space
  EXPECT_FALSE(RobotModel::FromString(latin1, "/tmp").ok());

  std::string with_nul = xml;
  with_nul.insert(with_nul.find("<link"), 1, '\0');
  auto nul = RobotModel::FromString(with_nul, "/tmp");
  ASSERT_FALSE(nul.ok());
  EXPECT_NE(nul.status().message().find("is NUL"), std::string::npos) << nul.status().message();
}

// A mimic joint must follow an actuated joint: one that mimicked itself or another mimic joint
// loaded, and completing its joint state then threw std::out_of_range (found by
// tests/fuzz/urdf_fuzz.cpp; the server completes the defaults of every robot it loads).
TEST(RobotModel, MimicOfAMimicJointIsRejected) {
  const auto urdf = [](const std::string& mimic_target) {
    return R"(<robot name="m"><link name="base"/><link name="a"/><link name="b"/>
      <joint name="j1" type="revolute"><parent link="base"/><child link="a"/><axis xyz="0 0 1"/>
        <limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
      <joint name="j2" type="revolute"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/>
        <limit lower="-1" upper="1" effort="1" velocity="1"/><mimic joint=")" + mimic_target + R"(" multiplier="2"/></joint>
      </robot>)";
  };
  auto self = RobotModel::FromString(urdf("j2"), "/tmp");
  ASSERT_FALSE(self.ok());
  EXPECT_EQ(self.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(self.status().message().find("joint 'j2' mimics 'j2', which is itself a mimic joint"), std::string::npos)
      << self.status().message();
  auto good = RobotModel::FromString(urdf("j1"), "/tmp");
  ASSERT_TRUE(good.ok()) << good.status().message();
  auto joints = good->CompleteJoints({{"j1", 0.25}});
  ASSERT_TRUE(joints.ok()) << joints.status().message();
  EXPECT_DOUBLE_EQ(joints->at("j2"), 0.5);
  // A state overshooting a limit (interpolated near it) is rejected as given and posed once clamped;
  // names the robot does not have are left for CompleteJoints to reject.
  EXPECT_FALSE(good->CompleteJoints({{"j1", 1.02}}).ok());
  const JointValues clamped = good->ClampedToLimits({{"j1", 1.02}, {"nope", 7.0}});
  EXPECT_DOUBLE_EQ(clamped.at("j1"), 1.0);
  EXPECT_DOUBLE_EQ(clamped.at("nope"), 7.0);
  EXPECT_DOUBLE_EQ(good->ClampedToLimits({{"j1", -3.0}}).at("j1"), -1.0);
  EXPECT_DOUBLE_EQ(good->ClampedToLimits({{"j1", 0.5}}).at("j1"), 0.5);
  EXPECT_TRUE(good->PosedMesh(good->ClampedToLimits({{"j1", 1.02}})).ok());
}

// A headset mesh saved and loaded again is the same mesh; PLY polygons are split into fans and a
// face naming a vertex the file does not have is a clear error, never a crash (assimp's own
// post-processing aborts on such faces).
TEST(MeshFile, PlyRoundTripPolygonsAndBadFaces) {
  const testing::ScopedTempDir tmp;
  TriangleMesh m;
  m.vertices = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0.5f}, {0, 1, 0.25f}};
  m.triangles = {{0, 1, 2}, {0, 2, 3}};
  const std::string saved = tmp.path() + "/two.ply";
  ASSERT_TRUE(SaveMeshFile(m, saved).ok());
  ASSERT_OK_AND_ASSIGN(const TriangleMesh back, LoadMeshFile(saved));
  ASSERT_EQ(back.triangles.size(), 2u);
  EXPECT_NEAR(back.SurfaceArea(), m.SurfaceArea(), 1e-6);

  const auto write = [&](const std::string& name, const std::string& faces, int face_count) {
    std::ofstream(tmp.path() + "/" + name) << "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\n"
                                              "property float y\nproperty float z\nelement face "
                                           << face_count
                                           << "\nproperty list uchar int vertex_index\nend_header\n"
                                              "0 0 0\n1 0 0\n1 1 0\n0 1 0\n"
                                           << faces;
    return tmp.path() + "/" + name;
  };
  ASSERT_OK_AND_ASSIGN(const TriangleMesh quad, LoadMeshFile(write("quad.ply", "4 0 1 2 3\n", 1)));
  EXPECT_EQ(quad.triangles.size(), 2u);
  EXPECT_NEAR(quad.SurfaceArea(), 1.0, 1e-6);
  const auto bad = LoadMeshFile(write("bad.ply", "3 0 1 2\n3 0 2 9\n", 2));
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.status().code(), StatusCode::kIoError);
  EXPECT_NE(bad.status().message().find("vertex 9"), std::string::npos) << bad.status().ToString();
}

// The text written to a .ply file in dir, then loaded.
Result<TriangleMesh> LoadPlyText(const testing::ScopedTempDir& dir, const std::string& text) {
  const std::string path = dir.path() + "/m.ply";
  std::ofstream(path, std::ios::binary | std::ios::trunc) << text;
  return LoadMeshFile(path);
}

// Assimp 5.2's PLY reader never returned on this header (a misspelt element line, then STL-like
// lines; found by tests/fuzz/mesh_fuzz.cpp): PLY headers are checked first and each fault is an
// IO_ERROR naming the line, so a URDF or a headset mesh cannot hang a load.
TEST(MeshFile, MalformedPlyHeaderIsAnErrorNotAHang) {
  const testing::ScopedTempDir tmp;
  const auto load = [&](const std::string& text) { return LoadPlyText(tmp, text); };
  const std::string body = "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
  const auto hang = load("ply\nformat ascii 1.0\nelement0 1\nouter loop\nvertex 0 0 0\nend_header\n" + body);
  ASSERT_FALSE(hang.ok());
  EXPECT_EQ(hang.status().code(), StatusCode::kIoError);
  EXPECT_NE(hang.status().message().find("PLY header line 3 ('element0 1'): not a PLY header keyword"),
            std::string::npos) << hang.status().message();

  const std::string header = "ply\nformat ascii 1.0\ncomment by hand\nelement vertex 3\nproperty float x\n"
                             "property float y\nproperty float z\nelement face 1\n";
  const auto no_property = load(header + "end_header\n" + body);
  ASSERT_FALSE(no_property.ok());
  EXPECT_NE(no_property.status().message().find("the last element has no property"), std::string::npos)
      << no_property.status().message();
  const auto no_end = load(header + "property list uchar int vertex_indices\n");
  ASSERT_FALSE(no_end.ok());
  EXPECT_NE(no_end.status().message().find("no end_header"), std::string::npos) << no_end.status().message();

  ASSERT_OK_AND_ASSIGN(const TriangleMesh fine,
                       load(header + "property list uchar int vertex_indices\nend_header\n" + body));
  EXPECT_EQ(fine.triangles.size(), 1u);

  // Assimp reserved gigabytes for an element named with twenty digits before its letters (the
  // fuzzer's, 2026-12-03): names start with a letter or '_'.
  const std::string vertices = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                               "property float z\n";
  const auto digits = load(vertices + "element " + std::string(20, '8') + "face 1\n"
                           "property list uchar int vertex_indices\nend_header\n" + body);
  ASSERT_FALSE(digits.ok());
  EXPECT_NE(digits.status().message().find("an element's name must start with a letter or '_'"), std::string::npos)
      << digits.status().message();
  const auto property = load(vertices + "element face 1\nproperty list uchar int 8indices\nend_header\n" + body);
  ASSERT_FALSE(property.ok());
  EXPECT_NE(property.status().message().find("a property's name must start with a letter or '_'"), std::string::npos)
      << property.status().message();
}

// Assimp 5.2's PLY reader allocated until the process died on this 223-byte file (a vertex
// coordinate of 70 digits, more than a float holds; found by tests/fuzz/mesh_fuzz.cpp). A PLY
// body is checked against its header first: each value one its type holds, each element's rows
// all there, each list within the file; the fault is an IO_ERROR naming element, row and value.
TEST(MeshFile, MalformedPlyBodyIsAnErrorNotAnExhaustedMachine) {
  const testing::ScopedTempDir tmp;
  const auto load = [&](const std::string& text) { return LoadPlyText(tmp, text); };
  const std::string header = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
                             "property float z\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n";
  const auto fault = [&](const std::string& body, const std::string& expected) {
    const auto r = load(header + body);
    ASSERT_FALSE(r.ok()) << body;
    EXPECT_EQ(r.status().code(), StatusCode::kIoError);
    EXPECT_NE(r.status().message().find(expected), std::string::npos) << r.status().message();
  };
  fault("0 0 0\n1" + std::string(68, '4') + " 0 t3 2\n",
        "element 'vertex' row 2 property 1: value '1444");  // the fuzzer's input
  fault("0 0 0\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n300 0 1 2\n", "element 'face' row 2 property 1: list count '300' is not a uint8");
  fault("0 0 0\n1 0 0\n1 1 0\n0 1 nan\n3 0 1 2\n3 0 2 3\n", "row 4 property 3: value 'nan' is not a float32");
  fault("0 0 0\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n3 0 2\n", "element 'face' row 2: the line ends before property 1");
  // One row a line, as assimp reads them: a row wrapped onto the next line made it read a face's
  // count from a vertex line (666666662) and allocate until the process died (the fuzzer's).
  fault("0 0 0\n1 0 0\n0 1 0\n1  \n666666662\n4 0 1 3 2\n", "element 'vertex' row 4: the line ends before property 2");
  fault("0 0 0 7\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n3 0 2 3\n", "element 'vertex' row 1: '7' beyond its 3 properties");
  fault("0 0 0\n1 0 0\n", "PLY body ends in element 'vertex' row 3 of 4");
  ASSERT_OK_AND_ASSIGN(const TriangleMesh fine, load(header + "0 0 0\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n3 0 2 3\n"));
  EXPECT_EQ(fine.triangles.size(), 2u);

  // Binary: a face whose int count claims 2^31 - 1 indices, in a file of a few bytes.
  std::string binary = "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n"
                       "property float y\nproperty float z\nelement face 1\nproperty list int int vertex_indices\nend_header\n";
  const float xyz[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
  binary.append(reinterpret_cast<const char*>(xyz), sizeof xyz);
  const std::int32_t face[4] = {3, 0, 1, 2};
  std::string huge = binary;
  binary.append(reinterpret_cast<const char*>(face), sizeof face);
  ASSERT_OK_AND_ASSIGN(const TriangleMesh one, load(binary));
  EXPECT_EQ(one.triangles.size(), 1u);
  const std::int32_t claim[2] = {2147483647, 0};
  huge.append(reinterpret_cast<const char*>(claim), sizeof claim);
  const auto r = load(huge);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("PLY body ends in element 'face' row 1 of 1"), std::string::npos)
      << r.status().message();
  // Headers are read strictly: assimp corrupted its heap on a binary file whose header held two
  // 'vertex' elements, and on one with binary bytes run into a property line.
  const std::string two = "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
                          "property float z\nelement vertex 2\nproperty float y\nend_header\n0 0 0\n1\n2\n";
  const auto twice = load(two);
  ASSERT_FALSE(twice.ok());
  EXPECT_NE(twice.status().message().find("a second element 'vertex'"), std::string::npos) << twice.status().message();
  const auto control = load(std::string("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\0\x0e\xff\n", 58) +
                            "end_header\n0\n");
  ASSERT_FALSE(control.ok());
  EXPECT_NE(control.status().message().find("('property float x??\xff'): a control character in the header"),
            std::string::npos)
      << control.status().message();
  const auto no_z = load("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n0 0\n");
  ASSERT_FALSE(no_z.ok());
  EXPECT_NE(no_z.status().message().find("element 'vertex' has no scalar property 'z'"), std::string::npos)
      << no_z.status().message();
  // Header types are checked too.
  const auto typo = load("ply\nformat ascii 1.0\nelement vertex 1\nproperty flaot x\nend_header\n0\n");
  ASSERT_FALSE(typo.ok());
  EXPECT_NE(typo.status().message().find("unknown type 'flaot'"), std::string::npos) << typo.status().message();
}

TEST(Kr5Package, Tool0AtZeroJoints) {
  ARREF_REQUIRE_SHARED();
  const RobotModel robot = LoadOrDie(Kr5PackageDir() + "/urdf/kr5_arc.urdf",
                                     RobotLoadOptions{.package_path = {testing::SharedDir() + "/robots"}});
  EXPECT_TRUE(Tool0(robot).translation().isApprox(Vec3(1.515, 0, 0.52), 1e-9));
  EXPECT_EQ(robot.ActuatedJoints().size(), 6u);
}

TEST(Kr5Package, PackageEntryMayBeThePackageItself) {
  ARREF_REQUIRE_SHARED();
  auto robot = RobotModel::Load(Kr5PackageDir() + "/urdf/kr5_arc.urdf",
                                RobotLoadOptions{.package_path = {Kr5PackageDir()}});
  EXPECT_TRUE(robot.ok()) << robot.status().ToString();
}

TEST(Kr5Package, DaeAndStlUrdfsGiveTheSameGeometry) {
  ARREF_REQUIRE_SHARED();
  const RobotModel dae = LoadOrDie(Kr5PackageDir() + "/urdf/kr5_arc.urdf",
                                   RobotLoadOptions{.package_path = {testing::SharedDir() + "/robots"}});
  const RobotModel stl = LoadOrDie(Kr5PackageDir() + "/urdf/kr5_arc_relative.urdf");
  for (const char* link : {"base_link", "link_1", "link_2", "link_3", "link_4", "link_5", "link_6"}) {
    const TriangleMesh* a = dae.LinkMesh(link);
    const TriangleMesh* b = stl.LinkMesh(link);
    ASSERT_TRUE(a && b) << link;
    EXPECT_EQ(a->triangles.size(), b->triangles.size()) << link;
    EXPECT_NEAR(a->SurfaceArea(), b->SurfaceArea(), 1e-4 * b->SurfaceArea()) << link;
    const Aabb ba = BoundsOf(a->vertices), bb = BoundsOf(b->vertices);
    EXPECT_TRUE(ba.min.isApprox(bb.min, 1e-3) && ba.max.isApprox(bb.max, 1e-3)) << link;
  }
  // Posed with the same joints, the whole robots coincide.
  const JointValues q = {{"joint_a1", 0.4}, {"joint_a2", -0.9}, {"joint_a3", 1.1}, {"joint_a5", 0.7}};
  const Aabb pa = BoundsOf(dae.PosedMesh(q)->vertices), pb = BoundsOf(stl.PosedMesh(q)->vertices);
  EXPECT_TRUE(pa.min.isApprox(pb.min, 1e-3) && pa.max.isApprox(pb.max, 1e-3));
}

TEST(Kr5Package, CollisionGeometryOnRequest) {
  ARREF_REQUIRE_SHARED();
  const RobotModel robot = LoadOrDie(Kr5PackageDir() + "/urdf/kr5_arc_relative.urdf",
                                     RobotLoadOptions{.package_path = {}, .geometry = GeometryKind::kCollision});
  // SOURCE.txt: the collision base_link has 1308 triangles, the visual one 8498.
  EXPECT_EQ(robot.LinkMesh("base_link")->triangles.size(), 1308u);
  const Aabb box = BoundsOf(robot.LinkMesh("link_2")->vertices);
  EXPECT_NEAR(box.max.x(), 0.668, 2e-3);
  EXPECT_NEAR(box.min.z(), -0.310, 2e-3);
}

// The links a joint motion leaves in place come from the kinematics: a prismatic joint carries
// its child and the child's children; a fixed link on the base stays.
TEST(JointMotion, UnmovedLinksAreThoseNoMovingJointCarries) {
  const testing::ScopedTempDir tmp;
  const RobotModel robot = LoadOrDie(WriteTestUrdf(tmp.path()));
  using Links = std::set<std::string>;
  ASSERT_OK_AND_ASSIGN(const Links slid, UnmovedLinks(robot, {}, {{"slide", {-0.2, 0.3}}}, 0.02));
  EXPECT_EQ(slid, (Links{"base", "scaled"}));
  ASSERT_OK_AND_ASSIGN(const Links spun, UnmovedLinks(robot, {{"slide", 0.5}}, {{"spin", {0.0, 1.0}}}, 0.02));
  EXPECT_EQ(spun, (Links{"base", "scaled", "slider"}));
  ASSERT_OK_AND_ASSIGN(const Links still, UnmovedLinks(robot, {}, {{"slide", {0.1, 0.11}}}, 0.02));
  EXPECT_EQ(still.size(), robot.GeometryLinks().size()) << "a range under min_range moves nothing";
  const auto unknown = UnmovedLinks(robot, {}, {{"follow", {0.0, 1.0}}}, 0.02);
  ASSERT_FALSE(unknown.ok()) << "a mimic joint is not set by itself";
  EXPECT_NE(unknown.status().message().find("'follow'"), std::string::npos) << unknown.status().message();
}

TEST(JointMotion, PosedMeshOfSomeLinksAndAClearErrorForAnUnknownOne) {
  const RobotModel robot = LoadOrDie(testing::BuiltinRobotUrdf());
  ASSERT_OK_AND_ASSIGN(const TriangleMesh whole, robot.PosedMesh({}));
  ASSERT_OK_AND_ASSIGN(const TriangleMesh base, robot.PosedMesh({}, {"base_link"}));
  EXPECT_NEAR(base.SurfaceArea(), robot.LinkMesh("base_link")->SurfaceArea(), 1e-6);
  EXPECT_LT(base.SurfaceArea(), whole.SurfaceArea());
  const auto bad = robot.PosedMesh({}, {"base_link", "no_such_link"});
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.status().message().find("'no_such_link'"), std::string::npos) << bad.status().message();
}

// The fit leaves the moving links out only when they are a large part of the robot and what
// stood still fixes the heading on the mesh's resolution (joint_motion.h).
TEST(JointMotion, ChooseMovingFitNeedsMuchMovedAndAFirmHeadingFromWhatStoodStill) {
  const RobotModel robot = LoadOrDie(testing::BuiltinRobotUrdf());
  const JointValues at = {{"joint_a2", -0.5}, {"joint_a3", 0.4}};
  auto choose = [&](const std::vector<std::string>& moving, double voxel_m) {
    JointRanges ranges;
    for (const std::string& j : moving) ranges[j] = {-0.3, 0.3};
    return ChooseMovingFit(robot, at, ranges, kJointMotionWhileMappingRad, voxel_m, kMovingFitMinLeverageVoxels,
                           kMovingFitMinMovedShare);
  };
  const std::vector<std::string> arm = {"joint_a2", "joint_a3", "joint_a4", "joint_a5", "joint_a6"};
  ASSERT_OK_AND_ASSIGN(const MovingFit fine, choose(arm, 0.03));
  ASSERT_TRUE(fine.links.has_value()) << "leverage " << fine.yaw_leverage_m;
  EXPECT_EQ(*fine.links, (std::set<std::string>{"base_link", "link_1"}));
  EXPECT_GT(fine.unmoved_area_share, 0.2);
  EXPECT_LT(fine.unmoved_area_share, 2.0 / 3.0);
  ASSERT_OK_AND_ASSIGN(const MovingFit coarse, choose(arm, 0.06));
  EXPECT_FALSE(coarse.links.has_value()) << "a 6 cm mesh: the turret's " << coarse.yaw_leverage_m << " m lever is under two edges";
  EXPECT_EQ(coarse.unmoved, fine.unmoved);
  ASSERT_OK_AND_ASSIGN(const MovingFit wrist, choose({"joint_a4", "joint_a5", "joint_a6"}, 0.01));
  EXPECT_FALSE(wrist.links.has_value()) << "the wrist is under a third of the surface: " << wrist.unmoved_area_share;
  ASSERT_OK_AND_ASSIGN(const MovingFit none, choose({}, 0.03));
  EXPECT_FALSE(none.links.has_value());
  EXPECT_EQ(none.unmoved.size(), robot.GeometryLinks().size());
}

// What a robot stands on is its fixed links: an arm reaching below its mounting surface (from
// a pedestal) does not lower it. The built-in robot's base casting ends at its origin; the test
// robot's fixed links are its base (a unit cube) and a cube scaled to 2 m, bolted to it.
TEST(JointMotion, TheRobotRestsOnItsFixedLinksNotOnAnArmReachingBelowThem) {
  const RobotModel builtin = LoadOrDie(testing::BuiltinRobotUrdf());
  using Links = std::set<std::string>;
  ASSERT_OK_AND_ASSIGN(const Links fixed, FixedLinks(builtin));
  EXPECT_EQ(fixed, (Links{"base_link"}));
  ASSERT_OK_AND_ASSIGN(const TriangleMesh reaching, builtin.PosedMesh({{"joint_a2", 0.3}, {"joint_a3", 1.0}}));
  ASSERT_LT(BoundsOf(reaching.vertices).min.z(), -0.3) << "the wrist reaches below the base";
  ASSERT_OK_AND_ASSIGN(const double rest, RestingHeight(builtin));
  EXPECT_DOUBLE_EQ(rest, 0.0);

  const testing::ScopedTempDir tmp;
  const RobotModel test_bot = LoadOrDie(WriteTestUrdf(tmp.path()));
  ASSERT_OK_AND_ASSIGN(const Links bolted, FixedLinks(test_bot));
  EXPECT_EQ(bolted, (Links{"base", "scaled"})) << "the slider and its wheel move";
  ASSERT_OK_AND_ASSIGN(const double low, RestingHeight(test_bot));
  EXPECT_NEAR(low, -1.0, 1e-6) << "a fixed link below the origin: its lowest point";
}

}  // namespace
}  // namespace arref
